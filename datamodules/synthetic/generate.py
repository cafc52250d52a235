"""Generate a whole sequence: build the colon, plan the path, render, write the layout.

Output (docs/datasets.md, Sequence layout; via :class:`c3f_slam.io.SequenceWriter`)::

    OUT/
      rgb/NNNNNN.png      uint8 RGB
      depth/NNNNNN.png    uint16, camera.depth_scale units per metre (exact ray-cast depth)
      camera.json         intrinsics (pinhole, no distortion)
      poses.txt           TUM, camera-to-world, metres, timestamps = index / fps
      mesh.ply            the ground-truth mesh the depth was ray cast against
      params.json         seed and every parameter (``generate --config params.json`` replays it)
      frames.csv          per frame: time, arc length, event label (the event's frames and
                          its ramps in and out), wall distance
      nuisances.json      only with nuisance.* on: frame index -> the nuisances of that frame
      tissue_mask.png     only with nuisance.border: uint8, 255 = tissue (depth is 0 elsewhere)
      covered/NNNNNN.png  only with recording fluid, bubbles or specular on: uint8, 255 = pixel
                          changed by fluid or bubbles, 128 = by an added highlight, 0 = as rendered
                          (training leaves the non-zero pixels out of its losses)
      recording.json      only with recording.* on: frame index -> the recording effects of that
                          frame, and the share of its pixels covered

Nuisances of real recordings (``SimParams.nuisance``, :mod:`datamodules.synthetic.nuisances`) are
applied to the rendered frames of this layout only; a repeated frame carries the pose and depth
of the frame it repeats (poses.txt), while frames.csv keeps the planned path. With every nuisance
off the files are exactly those of the simulator without them (params.json has no ``nuisance``
group while it holds the defaults).

Recording effects (``SimParams.recording``, :mod:`datamodules.synthetic.recording`) are applied
in their physical place around the nuisances: first what the scene, the light and the sensor add
(:data:`~datamodules.synthetic.recording.SCENE_EFFECTS`: fluid, bubbles, extra highlights, light,
sensor noise, interlacing; kept inside the border's tissue mask), then the nuisances (the
optics' blur and the video processor's border and overlay), then what the recorder adds to the
processor's output (:data:`~datamodules.synthetic.recording.CODEC_EFFECTS`: JPEG per frame, the
video round trip in chunks of ``recording.video_chunk`` frames). One simplification: a frame
the nuisances blur is blurred after its sensor noise (a real sensor adds it after the optics).
The effects are image-only: depth and poses are those of the sequence without them; a repeated
frame (``nuisance.repeat_share``) carries the covered mask of the frame it repeats. Off (the
default) the files are exactly those of the simulator without them (params.json has no
``recording`` group while it holds the defaults).

The sequence is written into a hidden sibling folder and renamed to OUT at the end, so an
interrupted run never leaves a half sequence under OUT; an existing non-empty OUT is only
replaced with ``overwrite=True``. Parameters are checked when they are made (frozen
:class:`~datamodules.synthetic.params.SimParams`), before anything is written.
"""

from __future__ import annotations

import csv
import json
import shutil
from collections import deque
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path

import cv2
import numpy as np
import open3d as o3d

from c3f_core.atomic import move_into_place, staging_dir
from c3f_slam.io import SequenceWriter
from datamodules.synthetic.layouts import layout_writer
from datamodules.synthetic.nuisances import NuisanceChain
from datamodules.synthetic.params import (
    PAPER_COMMON,
    PAPER_TABLE,
    NuisanceParams,
    SimParams,
    check_layout,
    check_output,
)
from datamodules.synthetic.recording import (
    CODEC_EFFECTS,
    SCENE_EFFECTS,
    RecordingChain,
    RecordingParams,
    video_roundtrip,
)
from datamodules.synthetic.scene import SimScene, build_scene, render_frames

FORMAT_VERSION = 1
__all__ = ["COVERED_FLUID", "COVERED_SPECULAR", "generate_sequence", "read_event_labels", "read_recording"]

COVERED_FLUID = 255  #: covered/ grey level of a pixel changed by fluid or bubbles
COVERED_SPECULAR = 128  #: covered/ grey level of a pixel of an added highlight (and no fluid or bubble)


def params_record(scene: SimScene) -> dict:
    p = scene.params
    c = scene.colon
    return {
        "generator": "datamodules.synthetic",
        "format_version": FORMAT_VERSION,
        "seed": p.seed,
        "preset": p.preset,
        "params": _params_dict(p),
        "paper_table": dict(PAPER_TABLE[p.preset], **PAPER_COMMON) if p.preset in PAPER_TABLE else None,
        "units": "metres, radians inside the code; params: lengths in m, angles in degrees",
        "camera": scene.camera.to_dict(),
        "mesh": {"vertices": int(len(c.vertices)), "triangles": int(len(c.triangles)), "length_m": c.length},
        "folds": [{"s": f.s, "sigma": f.sigma, "heights": list(f.heights)} for f in c.folds],
        "polyps": [{"s": q.s, "theta": q.theta, "radius": q.radius, "height": q.height} for q in c.polyps],
        "events": {k: int(sum(1 for x in scene.path.labels if x == k))
                   for k in ("closeup", "burst", "occluded", "roll")},
    }


def _params_dict(p: SimParams) -> dict:
    """Every parameter; the ``nuisance`` and ``recording`` groups only when they differ from the
    defaults (so sequences without them keep the params.json of the simulator before them)."""
    d = p.to_dict()
    if p.nuisance == NuisanceParams():
        d.pop("nuisance")
    if p.recording == RecordingParams():
        d.pop("recording")
    return d


def generate_sequence(
    params: SimParams,
    out: str | Path,
    *,
    overwrite: bool = False,
    progress: bool = True,
    layout: str = "c3f",
    on_frame: Callable[[int], None] | None = None,
) -> Path:
    """Render ``params`` into the folder ``out``; returns its path.

    ``layout``: ``c3f`` (the project's own, docs/datasets.md) or, additionally written from the
    same frames, ``uts`` / ``simcol3d`` / ``c3vd`` / ``colon10k`` (see :mod:`datamodules.synthetic.layouts`).
    """
    layout = check_layout(layout)
    out = check_output(out, overwrite).resolve()
    tmp = staging_dir(out)
    try:
        scene = build_scene(params)
        _write_all(scene, tmp, layout, progress, on_frame)
        move_into_place(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return out


def _write_all(scene: SimScene, root: Path, layout: str, progress: bool,
               on_frame: Callable[[int], None] | None) -> None:
    from tqdm import tqdm

    p = scene.params
    writer = SequenceWriter(root, scene.camera)
    extra = None
    if layout != "c3f":
        extra = layout_writer(layout, root / layout, scene)
    chain = NuisanceChain(p.nuisance, p.camera.width, p.camera.height, p.path.fps, p.seed) if p.nuisance.active() \
        else None
    rec = _Recording(p, root, chain) if p.recording.active() else None
    poses = scene.path.poses.copy()  # a repeated frame carries the pose of the frame it repeats
    names: dict[int, tuple[str, ...]] = {}
    pending: deque[Future] = deque()
    with ThreadPoolExecutor(max_workers=1) as pool:  # PNG encoding overlaps the next frame's rendering
        bar = tqdm(total=p.path.frames, desc=f"simulating {root.name.split('.partial-')[0].lstrip('.')}",
                   unit="frame", disable=not progress, leave=False)
        try:
            for i, rgb, depth in render_frames(scene):
                out_rgb = rec.scene(i, rgb) if rec is not None else rgb
                if chain is None:
                    out_depth = depth
                else:
                    f = chain.apply(i, out_rgb, depth)
                    poses[i], names[i] = scene.path.poses[f.source], f.names
                    out_rgb, out_depth = f.rgb, f.depth
                    if rec is not None:
                        rec.source(i, f.source)
                if rec is None:
                    pending.append(pool.submit(writer.write_frame, i, out_rgb, out_depth))
                else:
                    for j, rgb_j, depth_j, covered_j in rec.codec(i, out_rgb, out_depth):
                        pending.append(pool.submit(writer.write_frame, j, rgb_j, depth_j))
                        if covered_j is not None:
                            pending.append(pool.submit(_write_png, root / "covered" / f"{j:06d}.png", covered_j))
                if extra is not None:  # the published layouts get the frames as rendered
                    pending.append(pool.submit(extra.write_frame, i, rgb, depth))
                while len(pending) > 4:
                    pending.popleft().result()
                bar.update(1)
                if on_frame is not None:
                    on_frame(i)
            if rec is not None:
                for j, rgb_j, depth_j, covered_j in rec.flush():
                    pending.append(pool.submit(writer.write_frame, j, rgb_j, depth_j))
                    if covered_j is not None:
                        pending.append(pool.submit(_write_png, root / "covered" / f"{j:06d}.png", covered_j))
            while pending:
                pending.popleft().result()
        finally:
            bar.close()
    o3d.io.write_triangle_mesh(str(root / "mesh.ply"), scene.colon.to_legacy_mesh(), write_ascii=False,
                               compressed=False, write_vertex_normals=False, write_vertex_colors=False,
                               write_triangle_uvs=False, print_progress=False)
    (root / "params.json").write_text(json.dumps(params_record(scene), indent=2, sort_keys=True) + "\n")
    _write_frames_csv(scene, root / "frames.csv")
    if chain is not None:
        chain.write_truth(root, names)
    if rec is not None:
        rec.write_truth()
    if extra is not None:
        extra.finish()
    stamps = np.arange(p.path.frames, dtype=np.float64) / p.path.fps
    writer.finish(poses, stamps)


def _write_png(path: Path, img: np.ndarray) -> None:
    if not cv2.imwrite(str(path), img):
        raise OSError(f"could not write {path}")


class _Recording:
    """The recording effects of one sequence around its nuisances (module docstring): :meth:`scene`
    before them, :meth:`source` to follow a repeated frame, :meth:`codec` after them (frames come
    back in order, held until their video chunk is complete), :meth:`flush` at the end."""

    def __init__(self, p: SimParams, root: Path, nuisances: NuisanceChain | None) -> None:
        r = p.recording
        self.p, self.root = r, root
        self.chain = RecordingChain(r, p.camera.width, p.camera.height, p.seed, p.path.fps)
        self.tissue = nuisances.mask if nuisances is not None and p.nuisance.border != "none" else None
        self.masks = any(n in self.chain.on for n in ("fluid", "bubbles", "specular"))
        if self.masks:
            (root / "covered").mkdir()
        self.names: dict[int, list[str]] = {}
        self.shares: dict[int, float] = {}
        self._current: tuple[list[str], np.ndarray | None] = ([], None)  # this frame's scene effects, mask
        self._last: tuple[list[str], np.ndarray | None] = ([], None)  # those of the previous output frame
        self._held: list[tuple[int, np.ndarray, np.ndarray, np.ndarray | None]] = []

    def scene(self, i: int, rgb: np.ndarray) -> np.ndarray:
        """Frame ``i`` as rendered -> with the scene, light and sensor effects."""
        f = self.chain.apply(i, rgb, self.tissue, only=SCENE_EFFECTS)
        covered = None
        if self.masks:
            covered = np.where(f.covered, np.uint8(COVERED_FLUID),
                               np.where(f.specular, np.uint8(COVERED_SPECULAR), np.uint8(0))).astype(np.uint8)
        self._current = (list(f.names), covered)
        return f.rgb

    def source(self, i: int, source: int) -> None:
        """The nuisances made frame ``i`` from rendered frame ``source``: when that is an earlier
        one (a repeat of the previous output frame), frame ``i`` has that frame's effects and mask."""
        if source != i:
            self._current = self._last

    def codec(self, i: int, rgb: np.ndarray, depth: np.ndarray):
        """Frame ``i`` after the nuisances -> the frames ready to write, (index, rgb, depth, covered)."""
        f = self.chain.apply(i, rgb, only=CODEC_EFFECTS)
        self._last = self._current
        self.names[i] = [*self._current[0], *f.names]
        covered = self._current[1]
        if covered is not None:
            self.shares[i] = float(np.count_nonzero(covered)) / covered.size
        self._held.append((i, f.rgb, depth, covered))
        if self.p.video == "none" or len(self._held) >= self.p.video_chunk:
            return self.flush()
        return []

    def flush(self) -> list[tuple[int, np.ndarray, np.ndarray, np.ndarray | None]]:
        held, self._held = self._held, []
        if held and self.p.video != "none":
            coded = video_roundtrip([h[1] for h in held], self.p.video, self.p.video_scale, self.p.video_chunk,
                                    self.chain.fps)
            held = [(j, c, d, m) for (j, _, d, m), c in zip(held, coded)]
            for j, *_ in held:
                self.names[j].append("video")
        return held

    def write_truth(self) -> None:
        """``recording.json``: frame index -> {"effects": names in the order of EFFECTS, "covered":
        share of the frame's pixels in covered/ (with fluid, bubbles or highlights on)}."""
        lines = []
        for i in sorted(self.names):
            rec = {"effects": self.names[i]}
            if i in self.shares:
                rec["covered"] = round(self.shares[i], 6)
            lines.append(f'  "{i}": {json.dumps(rec)}')
        (self.root / "recording.json").write_text("{\n" + ",\n".join(lines) + "\n}\n")


def read_recording(root: str | Path) -> dict[int, dict]:
    """A sequence's ``recording.json`` as frame index -> {"effects": [...], "covered": share};
    empty when the file is absent (no recording effects)."""
    path = Path(root) / "recording.json"
    if not path.is_file():
        return {}
    return {int(k): v for k, v in json.loads(path.read_text()).items()}


def _write_frames_csv(scene: SimScene, path: Path) -> None:
    fps = scene.params.path.fps
    lines = ["index,timestamp,s_m,event,wall_distance_mm"]
    for i, (s, label, d) in enumerate(zip(scene.path.controls.s, scene.path.labels, scene.path.wall_distance)):
        lines.append(f"{i},{i / fps:.6f},{s:.6f},{label},{d * 1000:.3f}")
    path.write_text("\n".join(lines) + "\n")


def read_event_labels(root: str | Path) -> list[str]:
    """Per-frame event labels of a generated sequence (frames.csv ``event`` column, in frame
    order; '' = a plain frame); an empty list when the folder has no frames.csv."""
    path = Path(root) / "frames.csv"
    if not path.is_file():
        return []
    with path.open(newline="") as fh:
        rows = sorted(csv.DictReader(fh), key=lambda r: int(r["index"]))
    return [r.get("event") or "" for r in rows]
