"""DepthNet ablation: the full C3Fusion objective vs the Monodepth2 baseline, trained identically.

All runs use the same simulator sequences, seed, steps, batch size and network (the small
CPU variant, configs/depthnet/small.yaml); only the loss switches differ: the Monodepth2
baseline (small.yaml + monodepth2.yaml), the full objective (small.yaml) and, with the setting ``variants``, the
full objective with one switch off (full-no-dc, full-no-extra, full-no-outlier,
full-no-specular), the baseline plus outlier removal, or the full objective with the weight of
L_dc ramped up from 0 (full-dc-warmup, ``model.loss.lambda_dc_warmup_steps``; not in the paper).
``--set model_overrides=KEY=VALUE`` overrides a model argument of every variant (e.g.
``loss.lambda_dc=0.01``).
``--init CKPT`` starts every variant from the weights of a checkpoint (``model.init_weights``;
e.g. a baseline run, to test the extra losses on a network that already predicts structure).
Each is then tested on held-out sequences with the project's metric function (per-image median
scaling), next to the score of a constant depth. Sq Rel and RMSE are printed in centimetres, as
the paper's table is.
Training throughput is images/s over the whole fit (data loading included).

    python -m benchmarks.protocols.depthnet_ablation --set steps=500
    python -m benchmarks.protocols.depthnet_ablation --set steps=150 \
        --set variants=full-no-dc,full-no-outlier --report runs/switches.md
    python -m benchmarks.protocols.depthnet_ablation --set steps=400 \
        --init runs/bench/depthnet_ablation/baseline/tb/version_0/checkpoints/last.ckpt --report runs/warm.md

Inputs: sequences missing from --data (default ``runs/bench/depthnet_ablation/data``) are
generated from presets and seeds (settings ``frames``, ``coverage``: keep the per-frame motion near
the paper's; the table's set-up line reports it); each variant's run goes beside that folder
(``runs/bench/depthnet_ablation/VARIANT``). Every network is trained here, from scratch unless
``--init`` names the checkpoint of an earlier run.

Writes benchmarks/results/depthnet_ablation.md (numbers + the command line) and its .json
(``--report``; ``--out`` its former name). Settings (``--print-config``: each with its default and
meaning): :class:`Settings`; ``--data`` and ``--init`` (paths) stay plain options.
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import dataclass
from pathlib import Path

from benchmarks.common import RESULTS, WORK
from benchmarks.common.depth_metrics import HEADER, METRICS, logged_test_metrics, metric_cells
from benchmarks.common.protocol_cli import REPORT_HELP, ProtocolCli, check_choices, check_not_empty
from benchmarks.common.report import Report
from benchmarks.common.simulate import SimSequence, ensure_sequence
from c3f_core.errors import InputError


def generate(data: Path, names: list[str], frames: int, size: int, coverage: float) -> None:
    """Sequence k of ``names`` in ``data``: preset seq(k mod 8 + 1), seed 100 + k (made unless it exists)."""
    for k, name in enumerate(names):
        spec = SimSequence(f"seq{k % 8 + 1}", 100 + k, frames, size, (f"path.coverage={coverage}",))
        ensure_sequence(spec, data / name, overwrite=True)


def motion_per_frame(data: Path, names: list[str]) -> dict[str, float]:
    """Ground-truth motion between consecutive frames, median over the given sequences' steps:
    rotation (degrees), translation (mm) and translation / the sequence's median depth."""
    import numpy as np

    from c3f_slam.evaluation.trajectory import frame_motion
    from c3f_slam.io.sequence import Sequence

    rot, trans, rel = [], [], []
    for name in names:
        seq = Sequence(data / name)
        m = frame_motion(np.asarray(seq.poses))
        depth = np.median([np.median(d[d > 0]) for d in (seq.read_depth(i) for i in range(0, len(seq), 10))])
        rot.append(m.rot_deg.median)
        trans.append(m.trans.median)
        rel.append(m.trans.median / depth)
    return {"rot_p50": float(np.median(rot)), "t_mm_p50": 1e3 * float(np.median(trans)),
            "t_rel_p50": float(np.median(rel))}


# name -> (configs, loss-switch overrides). "full-no-X" is the full objective with one switch off.
SMALL, BASELINE = ["configs/depthnet/small.yaml"], ["configs/depthnet/small.yaml", "configs/depthnet/monodepth2.yaml"]
VARIANTS = {
    "baseline": (BASELINE, {}),
    "full": (SMALL, {}),
    "full-no-dc": (SMALL, {"loss.use_depth_consistency": False}),
    "full-no-extra": (SMALL, {"loss.use_extra_photometric": False}),
    "full-no-outlier": (SMALL, {"loss.use_outlier_mask": False}),
    "full-no-specular": (SMALL, {"loss.use_specular_mask": False}),
    "baseline+outlier": (BASELINE, {"loss.use_outlier_mask": True}),
    "full-dc-warmup": (SMALL, {}),  # + loss.lambda_dc_warmup_steps (--dc-warmup-steps)
}
LABELS = {"baseline": "Monodepth2 baseline", "full": "C3Fusion (full)"}


def run(configs: list[str], overrides: dict, data: Path, *, train: list[str], test: list[str], steps: int, batch: int,
        size: int, root: Path, seed: int = 7) -> dict:
    from c3f_models.cli import main

    switches = [a for k, v in overrides.items()
                for a in (f"--model.init_args.{k}", str(v).lower() if isinstance(v, bool) else str(v))]
    common = [
        "--config", "configs/trainer/cpu_smoke.yaml", *[a for c in configs for a in ("--config", c)], *switches,
        "--data.data_dir", str(data), "--data.split.train", json.dumps(train), "--data.split.val", "[]",
        "--data.split.test", json.dumps(test), "--data.frames.size", f"[{size}, {size}]",
        "--data.loader.batch_size", str(batch),
        "--trainer.default_root_dir", str(root), "--trainer.logger.init_args.save_dir", str(root),
        "--trainer.enable_progress_bar", "false", "--seed_everything", str(seed),
    ]
    t0 = time.perf_counter()
    cli = main(["fit", *common, "--trainer.max_steps", str(steps), "--trainer.limit_train_batches", "1.0",
                "--trainer.max_epochs", "-1", "--trainer.limit_val_batches", "0"])
    fit_s = time.perf_counter() - t0
    ckpt = Path(cli.trainer.checkpoint_callback.last_model_path)
    cli = main(["test", *common, "--ckpt_path", str(ckpt), "--trainer.limit_test_batches", "1.0"])
    metrics = logged_test_metrics(cli.trainer.callback_metrics)
    metrics["images_per_s"] = steps * batch / fit_s
    return metrics


def constant_depth_metrics(data: Path, test: list[str], size: int) -> dict:
    """Metrics of a flat prediction on the test sequences' centre frames, same pipeline as ``test``.

    ``depth_cv`` here is the ground truth's own spatial coefficient of variation.
    """
    import torch

    from c3f_slam.evaluation.depth import depth_metrics
    from datamodules.config import FramesConfig, LoaderConfig, SplitConfig
    from datamodules.sequence import C3FSequenceDataModule

    dm = C3FSequenceDataModule(data_dir=str(data), split=SplitConfig(train=[], val=[], test=test),
                               frames=FramesConfig(size=(size, size)), loader=LoaderConfig(batch_size=8))
    dm.setup("test")
    sums: dict[str, float] = {}
    n = 0
    for batch in dm.test_dataloader():
        gt = batch["depth"][:, 1]
        m = depth_metrics(torch.ones_like(gt), gt)
        k = m["n_images"]
        for name in METRICS:
            sums[name] = sums.get(name, 0.0) + m[name] * k
        sums["depth_cv"] = sums.get("depth_cv", 0.0) + m["gt_cv"] * k
        n += k
    return {name: v / max(n, 1) for name, v in sums.items()}


@dataclass(frozen=True)
class Settings:
    """What depthnet_ablation measures."""

    train_seqs: int = 4  #: training sequences
    test_seqs: int = 2  #: held-out test sequences
    frames: int = 300  #: frames per sequence
    #: share of the colon each sequence travels (simulator path.coverage); with 300 frames, 0.15 moves ~0.6 mm
    #: and ~0.5 deg per frame. The generator's default (1.0) crosses the whole 1.25 m colon, at its 5 mm/frame
    #: cap for short sequences (the paper: ~0.3 mm/frame).
    coverage: float = 0.15
    size: int = 128  #: square frame size, pixels
    steps: int = 400  #: training steps of every variant
    batch: int = 4  #: batch size
    seed: int = 7  #: seed_everything of every run (the tables so far: 7)
    threads: int = 1  #: torch intra-op threads (1 is fastest on a shared 2-core machine)
    #: variants run: baseline, full, full-no-dc, full-no-extra, full-no-outlier, full-no-specular,
    #: baseline+outlier, full-dc-warmup (full-no-X: the full objective with one switch off)
    variants: tuple[str, ...] = ("baseline", "full")
    #: full-dc-warmup: steps over which the weight of L_dc ramps from 0 (none: half of steps)
    dc_warmup_steps: int | None = None
    #: model arguments KEY=VALUE for every variant, e.g. loss.lambda_dc=0.01
    model_overrides: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        check_not_empty(self, "variants")
        check_choices("variants", self.variants, VARIANTS)
        for kv in self.model_overrides:
            key, sep, _ = kv.partition("=")
            if not sep or not key.strip():
                raise InputError(f"model_overrides: expected KEY=VALUE, got {kv!r}")


CLI = ProtocolCli("depthnet_ablation", Settings, __doc__, example="steps=150")


def parse_args(argv: list[str] | None = None) -> tuple[argparse.Namespace, Settings, list[str], dict[str, str]]:
    """The plain options, the settings, the variants to run and the model overrides (checked before any work)."""
    ap = CLI.parser()
    ap.add_argument("--data", type=Path, default=WORK / "depthnet_ablation" / "data",
                    help="folder of the sequences (made when missing); the runs go beside it")
    ap.add_argument("--init", type=Path, default=None,
                    help="checkpoint whose weights start every variant (model.init_weights; optimiser not resumed)")
    ap.add_argument("--report", "--out", type=Path, default=RESULTS / "depthnet_ablation.md",
                    help=REPORT_HELP + " (--out: its former name)")
    a, settings = CLI.parse(ap, argv)
    if a.init is not None and not a.init.is_file():
        ap.error(f"--init: no such checkpoint: {a.init}")
    extra = {}
    for kv in settings.model_overrides:
        key, _, value = kv.partition("=")
        extra[key.strip()] = value.strip()
    return a, settings, list(settings.variants), extra


def run_variants(a: argparse.Namespace, settings: Settings, variants: list[str], *, extra: dict[str, str],
                 train: list[str], test: list[str], warmup: int) -> tuple[dict[str, dict], dict[str, str]]:
    """Train and test each variant; returns the metrics by table label and each variant's label."""
    tag = ("".join(f"-{k}={v}" for k, v in extra.items()) + ("-init" if a.init is not None else "")
           + (f"-seed{settings.seed}" if settings.seed != 7 else ""))
    results: dict[str, dict] = {}
    keys: dict[str, str] = {}
    for v in variants:
        cfg, overrides = VARIANTS[v]
        overrides = {**overrides, **extra}
        if v == "full-dc-warmup":
            overrides["loss.lambda_dc_warmup_steps"] = warmup
        if a.init is not None:
            overrides["init_weights"] = str(a.init.resolve())
        root = a.data.parent / (v.replace("+", "_plus_") + tag)
        keys[v] = LABELS.get(v, v) + (f" ({', '.join(settings.model_overrides)})" if extra else "")
        results[keys[v]] = run(cfg, overrides, a.data, train=train, test=test, steps=settings.steps,
                               batch=settings.batch, size=settings.size,
                               root=root, seed=settings.seed)
    return results, keys


def report_body(a: argparse.Namespace, settings: Settings, variants: list[str], *, extra: dict[str, str],
                motion: dict[str, float], results: dict[str, dict], keys: dict[str, str], warmup: int) -> list[str]:
    """The set-up paragraph, the table (one row per result) and the Sq Rel ratio of full / baseline."""
    head = (f"| method | {HEADER} | depth CV | train img/s |\n"
            "|---|---|---|---|---|---|---|---|---|---|\n")
    rows = "".join(
        f"| {n} | " + metric_cells(m)
        + f" | {m['depth_cv']:.3f} | " + (f"{m['images_per_s']:.2f}" if "images_per_s" in m else "-") + " |\n"
        for n, m in results.items()
    )
    ratio = ""
    if "baseline" in variants and "full" in variants:
        base, full = results[keys["baseline"]], results[keys["full"]]
        ratio = f"Sq Rel full / baseline = {full['sq_rel'] / base['sq_rel']:.3f} (paper: 0.049 / 0.058 = 0.845)\n"
    text = (
        f"Setup: ResNet18 without DCN (the small CPU variant), {settings.size}x{settings.size}, batch "
        f"{settings.batch}, {settings.steps} steps each, seed {settings.seed}, CPU ({settings.threads} torch thread)"
        + (f", every variant starting from the weights of {a.init} (optimiser not resumed)" if a.init else "")
        + (f", model overrides for every variant: {', '.join(settings.model_overrides)}" if extra else "")
        + (f", full-dc-warmup: weight of L_dc ramped from 0 over {warmup} steps"
           if "full-dc-warmup" in variants else "")
        + f". Data: simulator, {settings.train_seqs} training sequences and {settings.test_seqs} held-out test "
        f"sequences of {settings.frames} frames (presets seq1.., seeds 100+k, path.coverage {settings.coverage}; "
        f"ground-truth motion between consecutive frames, median of the sequences' medians: rotation "
        f"{motion['rot_p50']:.2f} deg, translation {motion['t_mm_p50']:.2f} mm, {100 * motion['t_rel_p50']:.1f} % "
        "of the median depth). "
        "Metrics on the test sequences only, per-image median scaling. "
        "Depth CV: spatial coefficient of variation of the predicted depth (std/mean over each image, averaged); "
        "the ground truth's is given in the reference row, and a CV near 0 means the network predicts a flat depth. "
        "The constant-depth row predicts the same depth everywhere (after median scaling: the ground-truth median), "
        "the score a network must beat to have learnt any structure.\n\n"
        + head + rows + "\n" + ratio
    )
    return [text]


def main(argv: list[str] | None = None) -> None:
    a, settings, variants, extra = parse_args(argv)
    import torch

    torch.set_num_threads(settings.threads)

    train = [f"train{k}" for k in range(settings.train_seqs)]
    test = [f"test{k}" for k in range(settings.test_seqs)]
    generate(a.data, train + test, settings.frames, settings.size, settings.coverage)
    motion = motion_per_frame(a.data, train + test)
    results = {"constant depth (reference)": constant_depth_metrics(a.data, test, settings.size)}
    warmup = settings.dc_warmup_steps if settings.dc_warmup_steps is not None else settings.steps // 2
    measured, keys = run_variants(a, settings, variants, extra=extra, train=train, test=test, warmup=warmup)
    results.update(measured)
    report = Report(__file__, "DepthNet ablation: full objective vs Monodepth2 baseline", argv)
    print(report.publish(a.report, report_body(a, settings, variants, extra=extra, motion=motion, results=results,
                                               keys=keys, warmup=warmup), settings,
                         data={"motion": motion, "results": results}, options=a))


if __name__ == "__main__":
    main()
