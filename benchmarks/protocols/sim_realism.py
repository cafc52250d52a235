"""How close do the simulator's frames look to real video, before and after randomised looks and
recording effects?

Real frames: every ``every``-th frame of the C3VD phantom clip (``--phantom DIR``, the folder with
``split.py``; its frames are split into the work folder and never enter the repository), inside
the clip's static black border (:func:`benchmarks.common.realism.static_border`).

Simulated frames, per preset of ``presets`` (seed :data:`FIRST_SEED` + its position):

- ``before``: the preset's defaults (``frames`` frames at ``size`` px, ``path.coverage=coverage``);
- ``after``: the same sequence with the look :func:`datamodules.synthetic.randomize.sample_look`
  draws for its seed (appearance, folds, border, blur, and the ``recording.*`` effects: light,
  sensor noise, fluid, bubbles, highlights, JPEG, video), inside its border's tissue mask.

Per set: the realism statistic (:func:`benchmarks.common.realism.realism`, lower = closer; 0 for
identical sets): pooled colour, gradient and noise histogram distances and ``nearest``, each
simulated frame's descriptor distance to the nearest real frame, averaged over the frames (the
headline: it does not reward a set for being as uniform as the phantom's single scene; the
Frechet distance, which does, is listed beside it as a diagnostic). A contact sheet (``--sheet``):
a row of "before", a row of "after", one tile per recording effect alone (``--sheet-phantom``:
a first row of phantom thumbnails, for local use only).

    python -m benchmarks.protocols.sim_realism --phantom ../shared/data/c3vd_phantom_preview
    python -m benchmarks.protocols.sim_realism --phantom DIR --set frames=12 --report /tmp/sim_realism.md

Settings (``--print-config``: each with its default and meaning): :class:`Settings`; ``--phantom``
names an input and ``--sheet`` an output (paths), plain options.
"""

from __future__ import annotations

import sys
import zlib
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from benchmarks.common import RESULTS, WORK
from benchmarks.common.protocol_cli import REPORT_HELP, WORK_HELP, ProtocolCli, check_not_empty
from benchmarks.common.realism import DIAGNOSTICS, TERMS, nearest_distances, realism, static_border
from benchmarks.common.report import Report
from benchmarks.common.simulate import SimSequence, ensure_sequence
from c3f_core.errors import InputError
from datamodules.synthetic.randomize import sample_look
from datamodules.synthetic.recording import RecordingChain, RecordingParams

FIRST_SEED = 7701  #: the sequence of preset k has seed FIRST_SEED + k (seeds no other benchmark uses)
#: one recording effect alone per tile of the sheet's last row (strong, to be seen at tile size)
EFFECT_TILES = {
    "fluid": {"fluid_share": 1.0, "fluid_cover": 0.25},
    "bubbles": {"bubbles_share": 1.0, "bubbles_count": 10},
    "specular": {"specular_share": 1.0},
    "light": {"gain_r": 1.25, "gain_b": 0.75, "falloff": 1.0, "uneven": 0.5},
    "noise": {"noise": 0.4, "noise_grain_px": 0.8},
    "interlace": {"interlace_share": 1.0, "interlace_px": 3.0},
    "jpeg q30": {"jpeg_share": 1.0, "jpeg_quality_min": 30, "jpeg_quality_max": 30},
    "mp4v x0.5": {"video": "mp4v", "video_scale": 0.5},
}


@dataclass(frozen=True)
class Settings:
    """What sim_realism measures."""

    presets: tuple[str, ...] = ("seq1", "seq3", "seq5")  #: simulator presets, one sequence each
    frames: int = 24  #: frames per simulated sequence
    size: int = 128  #: square simulated frame size, pixels (the statistic compares at 128 px)
    coverage: float = 0.1  #: path.coverage of the simulated sequences (share of the colon travelled)
    every: int = 8  #: take every N-th frame of the phantom clip
    tile: int = 128  #: contact sheet tile size, pixels

    def __post_init__(self) -> None:
        check_not_empty(self, "presets")
        for name in ("frames", "size", "every", "tile"):
            if getattr(self, name) < 1:
                raise InputError(f"{name}: must be at least 1, got {getattr(self, name)}")


CLI = ProtocolCli("sim_realism", Settings, __doc__, example="frames=12")


def read_rgb(path: Path) -> np.ndarray:
    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if img is None:
        raise InputError(f"cannot read {path}")
    return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)


def phantom_frames(phantom: Path, work: Path, every: int) -> tuple[list[np.ndarray], np.ndarray]:
    """Every ``every``-th frame of the phantom clip (its split, or the clip's folder split by its
    split.py into ``work``: :func:`datamodules.phantom.split_folder`) and the clip's tissue mask
    (from all its frames)."""
    from datamodules.phantom import split_folder

    folder = split_folder(phantom, work)
    everything = [read_rgb(p) for p in sorted((folder / "rgb").glob("*.png"))]
    return everything[::every], static_border(everything)


def sequence_frames(seq: Path) -> tuple[list[np.ndarray], np.ndarray | None]:
    """A sequence's frames and its tissue mask (None without a border)."""
    frames = [read_rgb(p) for p in sorted((seq / "rgb").glob("*.png"))]
    mask = seq / "tissue_mask.png"
    return frames, (cv2.imread(str(mask), cv2.IMREAD_GRAYSCALE) > 0 if mask.is_file() else None)


def tile(img: np.ndarray, size: int, label: str = "") -> np.ndarray:
    """``img`` fitted into a black ``size`` x ``size`` tile, ``label`` written at its top left."""
    h, w = img.shape[:2]
    s = size / max(h, w)
    small = cv2.resize(img, (round(w * s), round(h * s)), interpolation=cv2.INTER_AREA if s < 1 else cv2.INTER_CUBIC)
    out = np.zeros((size, size, 3), np.uint8)
    y0, x0 = (size - small.shape[0]) // 2, (size - small.shape[1]) // 2
    out[y0:y0 + small.shape[0], x0:x0 + small.shape[1]] = small
    if label:
        scale = 0.36 * size / 128
        cv2.putText(out, label, (4, round(13 * size / 128)), cv2.FONT_HERSHEY_SIMPLEX, scale, (0, 0, 0), 3, cv2.LINE_AA)
        cv2.putText(out, label, (4, round(13 * size / 128)), cv2.FONT_HERSHEY_SIMPLEX, scale, (255, 255, 120), 1,
                    cv2.LINE_AA)
    return out


def spread(items: list, n: int) -> list:
    """``n`` items evenly spread over ``items``."""
    if len(items) <= n:
        return list(items)
    return [items[round(k * (len(items) - 1) / (n - 1))] for k in range(n)]


def contact_sheet(rows: list[list[np.ndarray]], labels: list[str], size: int) -> np.ndarray:
    """Rows of frames as labelled tiles (the first tile of a row carries the row's label; a row
    whose frames are already tiles is taken as it is)."""
    cols = max(len(r) for r in rows)
    blank = np.full((size, size, 3), 32, np.uint8)
    lines = []
    for frames, label in zip(rows, labels):
        tiles = [f if f.shape == (size, size, 3) and not label else tile(f, size, label if k == 0 else "")
                 for k, f in enumerate(frames)]
        lines.append(np.hstack([*tiles, *[blank] * (cols - len(tiles))]))
    return np.vstack(lines)


def effect_tiles(frame: np.ndarray, size: int, seed: int) -> list[np.ndarray]:
    """``frame`` as rendered, then with each effect of :data:`EFFECT_TILES` alone, labelled."""
    h, w = frame.shape[:2]
    out = [tile(frame, size, "rendered")]
    for label, kw in EFFECT_TILES.items():
        chain = RecordingChain(RecordingParams(**kw), w, h, seed=seed)
        out.append(tile(chain.apply_sequence([frame, frame])[1].rgb, size, label))
    return out


def _row(name: str, s: dict) -> str:
    return f"| {name} | " + " | ".join(f"{s[t]:.4f}" for t in (*TERMS, "total", *DIAGNOSTICS)) + " |"


def main(argv: list[str] | None = None) -> int:
    ap = CLI.parser()
    ap.add_argument("--phantom", type=Path, help="the phantom clip's folder (with split.py): the real frames")
    ap.add_argument("--sheet", type=Path, help="contact sheet PNG (default: WORK/sheet.png)")
    ap.add_argument("--sheet-phantom", action="store_true", help="a first row of phantom thumbnails in the sheet")
    ap.add_argument("--work", type=Path, default=WORK / "sim_realism", help=WORK_HELP)
    ap.add_argument("--report", type=Path, default=RESULTS / "sim_realism.md", help=REPORT_HELP)
    args, settings = CLI.parse(ap, argv)
    if args.phantom is None:
        ap.error("--phantom: give the phantom clip's folder (with split.py)")
    real, real_mask = phantom_frames(args.phantom.resolve(), args.work, settings.every)
    base = (f"path.coverage={settings.coverage}",)
    sets: dict[str, dict[str, list]] = {v: {"frames": [], "masks": [], "preset": []} for v in ("before", "after")}
    looks: dict[str, list[str]] = {}
    for k, preset in enumerate(settings.presets):
        seed = FIRST_SEED + k
        look = sample_look(seed)
        looks[f"{preset}/{seed}"] = list(look)
        key = f"{zlib.crc32(' '.join(look).encode()):08x}"  # a changed look is a new sequence
        for variant, items, name in (("before", base, f"{preset}_{seed}"),
                                     ("after", (*base, *look), f"{preset}_{seed}_look{key}")):
            seq = ensure_sequence(SimSequence(preset, seed, settings.frames, settings.size, items),
                                  args.work / variant / name)
            frames, tissue = sequence_frames(seq)
            full = np.ones(frames[0].shape[:2], bool)
            sets[variant]["frames"] += frames
            sets[variant]["masks"] += [tissue if tissue is not None else full] * len(frames)
            sets[variant]["preset"] += [preset] * len(frames)
            print(f"{variant} {name}: {len(frames)} frames", flush=True)
    scores, per_preset = {}, {}
    for variant, s in sets.items():
        scores[variant] = realism(s["frames"], real, masks=s["masks"], real_masks=real_mask, size=settings.size)
        per = nearest_distances(s["frames"], real, masks=s["masks"], real_masks=real_mask, size=settings.size)
        presets = np.array(s["preset"])
        per_preset[variant] = {p: float(per[presets == p].mean()) for p in settings.presets}
        scores[variant]["nearest_median"] = float(np.median(per))
        scores[variant]["nearest_p90"] = float(np.quantile(per, 0.9))
    b, a = scores["before"], scores["after"]
    body = [
        f"Real: {len(real)} frames of the C3VD phantom clip (every {settings.every}th of its frames, inside its "
        f"border). Simulated: presets {', '.join(settings.presets)}, seeds {FIRST_SEED}-"
        f"{FIRST_SEED + len(settings.presets) - 1}, {settings.frames} frames each at {settings.size} px "
        f"(path.coverage {settings.coverage:g}); before = the preset's defaults, after = the same sequences with "
        "the look `sample_look(seed)` draws (appearance, folds, border, blur and the recording effects). Lower = "
        "closer to the real frames, 0 = identical sets. `nearest`: each simulated frame's descriptor distance "
        "(hue, saturation, value and gradient histograms; mean Hellinger distance) to the nearest real frame, "
        "averaged over the frames; colour, gradient, noise: 1-D Wasserstein distances of the pooled histograms; "
        "total: the mean of those four. Frechet: the Frechet distance of Gaussians fitted to the descriptors, a "
        "diagnostic outside the total (it also compares the sets' spreads, so a set varied on purpose pays "
        "for its variety against one phantom scene).",
        "",
        "| set | colour | gradient | noise | nearest | total | frechet |",
        "|---|---|---|---|---|---|---|",
        _row("before", b),
        _row("after", a),
        "",
        "Per-frame `nearest` by preset (mean over its frames), and over all frames its median and 90th "
        "percentile:",
        "",
        "| set | " + " | ".join(settings.presets) + " | median | 90th percentile |",
        "|---|" + "---|" * (len(settings.presets) + 2),
        *[f"| {v} | " + " | ".join(f"{per_preset[v][p]:.4f}" for p in settings.presets)
          + f" | {scores[v]['nearest_median']:.4f} | {scores[v]['nearest_p90']:.4f} |" for v in ("before", "after")],
    ]
    cols = len(EFFECT_TILES) + 1
    n = len(sets["before"]["frames"])
    probe = sets["before"]["frames"][n // (2 * len(settings.presets))]
    rows = [spread(sets["before"]["frames"], cols), spread(sets["after"]["frames"], cols),
            effect_tiles(probe, settings.tile, FIRST_SEED)]
    labels = ["before", "after", ""]
    if args.sheet_phantom:
        rows, labels = [spread(real, cols), *rows], ["phantom", *labels]
    sheet = args.sheet or args.work / "sheet.png"
    sheet.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(sheet), cv2.cvtColor(contact_sheet(rows, labels, settings.tile), cv2.COLOR_RGB2BGR))
    data = {"scores": scores, "nearest_by_preset": per_preset, "looks": looks, "real_frames": len(real)}
    report = Report(__file__, "Simulator realism: frames against real video, before and after randomised looks",
                    argv)
    report.publish(args.report, body, settings, data, options=args)
    print("\n".join(body))
    print(f"contact sheet: {sheet}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
