"""Speed of the SLAM runtime, before vs after, side by side in one run: frames/s and ms per
frame per stage, with the ATE and registered share of each run (speed must not cost accuracy).

Variants, run with the CLI one after another (runs alternate so machine noise hits all alike):

- ``baseline`` (with ``--baseline CHECKOUT``): the code before, from that checkout, its defaults;
- ``serial``: this checkout as the loop was: each frame perceived (read, depth, keypoints,
  descriptors) in the run loop (``frames.prefetch=0``), each new frame matched against every
  earlier frame of its fragment (``fragments.intra_all_pairs=true``), ContraFeat's dense graph;
- ``prefetch``: only perception beside tracking, by one worker thread;
- ``bounded``: only the bounded intra-fragment matching;
- ``one-worker``: the defaults but one perception thread (``frames.perception_workers=1``);
- ``after``: the defaults (both, ContraFeat's keypoint graph where the export has one, and two
  perception threads: two frames' networks and SIFT at once, beside the back-end).

Cases (setting ``cases``): ``rgbd-128`` (simulator colon, 128 px, true depth, SIFT), ``rgbd-640x480``
(the synthetic room at 640x480 with Kinect-like noise, room preset, true depth, SIFT),
``model-128`` (simulator colon at 128 px, the zoo's DepthNet and ContraFeat) and ``model-224``
(simulator colon at 224 px, the paper-size networks: DepthNet ResNet50 + DCN and ContraFeat
ResNet18-FPN, 128-d, random weights: speed does not depend on the weight values).

    python -m benchmarks.protocols.slam_speed --baseline /tmp/before
    python -m benchmarks.protocols.slam_speed --set cases=rgbd-128 --set frames=300 --report /tmp/slam_speed.md

Inputs: every sequence is generated from its seed under ``--work`` (default
``runs/bench/slam_speed``); the zoo's models by name; the paper-size exports made from random
weights with the project's exporter. Memory over a long stream: ``slam_scale.md``.
Writes benchmarks/results/slam_speed.md and its .json. Settings (``--print-config``: each with its
default and meaning): :class:`Settings`; ``--baseline`` (a checkout) stays a plain option.
"""

from __future__ import annotations

import argparse
import os
import platform
import shutil
import statistics
import sys
from dataclasses import dataclass
from pathlib import Path

from benchmarks.common import RESULTS, ROOT, WORK
from benchmarks.common.protocol_cli import REPORT_HELP, WORK_HELP, ProtocolCli, check_choices, check_not_empty
from benchmarks.common.report import Report
from benchmarks.common.simulate import SimSequence, ensure_sequence
from benchmarks.common.slam_run import run_and_score
from c3f_core.errors import InputError

NO_EVENTS = ("path.closeups=0", "path.bursts=0", "path.occlusions=0", "path.roll_events=0")
BASELINE = "baseline"  #: the variant run from ``--baseline CHECKOUT`` with its defaults
VARIANTS: dict[str, tuple[str, ...]] = {  # --set overrides of this checkout's defaults
    "serial": ("frames.prefetch=0", "fragments.intra_all_pairs=true"),
    "prefetch": ("fragments.intra_all_pairs=true", "frames.perception_workers=1"),
    "bounded": ("frames.prefetch=0",),
    "one-worker": ("frames.perception_workers=1",),
    "after": (),
}
DENSE_ONLY = (BASELINE, "serial", "prefetch", "bounded")  # variants given ContraFeat's dense graph alone
STAGES = ("io", "depth", "keypoints", "wait", "matching", "fallback", "refine", "posegraph", "fusion")
PERCEPTION = ("io", "depth", "keypoints")


@dataclass(frozen=True)
class Case:
    """One input: a sequence, the preset, and the models (None: true depth, SIFT)."""

    name: str
    preset: str
    what: str
    models: str | None = None  # "zoo" | "paper"


CASES = {
    "rgbd-128": Case("rgbd-128", "colon", "simulator colon seq1 (no events), 128 px, true depth, SIFT"),
    "rgbd-640x480": Case("rgbd-640x480", "room", "synthetic room, 640x480, Kinect-like depth noise, SIFT"),
    "model-128": Case("model-128", "colon", "simulator colon seq1 (no events), 128 px, zoo DepthNet + ContraFeat",
                      "zoo"),
    "model-224": Case("model-224", "colon", "simulator colon seq1 (no events), 224 px, paper-size DepthNet "
                      "(ResNet50 + DCN) + ContraFeat (ResNet18-FPN, 128-d), random weights", "paper"),
}
ZOO = ("zoo:c3f-depth-r18w32", "zoo:c3f-features-r18w32")


def sequence(case: Case, frames: int, work: Path) -> Path:
    """The case's sequence under ``work`` (generated once)."""
    out = work / "data" / f"{case.name}_{frames}"
    if case.name == "rgbd-640x480":
        if not (out / "camera.json").is_file():
            from datamodules.synthetic.room import room_sequence

            shutil.rmtree(out, ignore_errors=True)
            room_sequence(out, frames=frames, width=640, height=480, seed=0)
        return out
    size = 224 if case.name == "model-224" else 128
    return ensure_sequence(SimSequence("seq1", 1, frames, size, NO_EVENTS), out, echo=True)


def paper_size_models(seq: Path, work: Path) -> tuple[Path, Path]:
    """(depth, descriptors) ONNX exports of the paper-size networks with random weights (made once)."""
    out = work / "paper_size_models"
    depth, feat = out / "depthnet.onnx", out / "contrafeat.onnx"
    if depth.is_file() and feat.is_file():
        return depth, feat
    import torch

    from c3f_models.contrafeat.module import ContraFeat
    from c3f_models.depth.module import DepthNet
    from export import export_model

    torch.manual_seed(0)
    models = (DepthNet(network={"encoder_layers": 50, "dcn": True}), ContraFeat(
        network={"backbone_layers": 18, "descriptor_dim": 128, "fpn_channels": 128, "stem_channels": 32,
                 "head_channels": 128}))
    out.mkdir(parents=True, exist_ok=True)
    for model, graphs in zip(models, (["depth"], None), strict=True):
        ckpt = out / f"{type(model).__name__}.pt"
        torch.save(model.state_dict(), ckpt)
        export_model(model, ckpt, out, frames=seq, graphs=graphs, num_frames=2)
    return depth, feat


def model_options(case: Case, variant: str, seq: Path, work: Path, threads: int | None,
                  models: tuple[Path, Path] | None = None) -> list[str]:
    """The run's model options (none for true depth and SIFT); ``models``: (depth, descriptors)
    files in place of the case's for this checkout's variants (the baseline keeps the case's)."""
    if case.models is None:
        return ["--depth-source", "files", "--descriptors", "sift"]
    depth, feat = ZOO if case.models == "zoo" else paper_size_models(seq, work)
    if models is not None and variant != BASELINE:
        depth, feat = models
    if variant in DENSE_ONLY:
        feat = dense_only(feat, work)
    threads_option = ["--threads", str(threads)] if threads else []
    return ["--depth-model", str(depth), "--feature-model", str(feat), *threads_option]


def dense_only(feat: str | Path, work: Path) -> str | Path:
    """The dense-graph ContraFeat file alone in a folder of its own, so that the runtime does not
    find the export's keypoint graph beside it (a zoo name as it is: the zoo has no keypoint graph)."""
    if str(feat).startswith("zoo:"):
        return feat
    from c3f_slam.models.zoo import sha256_of

    alone = work / "dense_only" / sha256_of(feat)[:16] / Path(feat).name  # one folder per file content
    if not alone.is_file():
        alone.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(feat, alone)
    return alone


def run_once(case: Case, variant: str, seq: Path, *, work: Path, threads: int | None, baseline: Path | None,
             providers: str | None = None, models: tuple[Path, Path] | None = None) -> dict:
    """One run of ``variant`` on ``case`` with the CLI (``baseline``: that checkout, its defaults;
    else this one with the variant's settings): its summary with the ATE (Sim(3), cm)."""
    out = work / "runs" / case.name / variant
    checkout = baseline if variant == BASELINE else ROOT
    sets = [] if variant == BASELINE else [x for kv in VARIANTS[variant] for x in ("--set", kv)]
    cmd = [sys.executable, "-m", "c3f_slam", "run", str(seq), "--out", str(out), "--overwrite", "--quiet",
           "--preset", case.preset, "--set", "coverage.enabled=false", *sets,
           *model_options(case, variant, seq, work, threads, models),
           *(["--providers", providers] if providers and case.models and variant != BASELINE else [])]
    s, ev = run_and_score(cmd, out, seq, f"{case.name} {variant}", cwd=checkout,
                          env={**os.environ, "PYTHONPATH": str(checkout)})
    s["ate_sim3_cm"] = 100 * ev.get("ate_sim3", {}).get("rmse_m", float("nan"))
    s["fps"] = s["frames"] / s["wall_seconds"]
    return s


def ms(s: dict, stage: str) -> float:
    return s["timings"].get(stage, {}).get("ms_per_frame", 0.0)


def row(case: Case, variant: str, runs: list[dict], base_fps: float) -> tuple[str, dict]:
    """The table row of one variant (medians over the repeats) and its numbers."""
    fps = statistics.median(r["fps"] for r in runs)
    stage = {k: statistics.median(ms(r, k) for r in runs) for k in STAGES}
    frame_ms = 1000.0 / fps
    perception = sum(stage[k] for k in PERCEPTION)
    backend = sum(v for k, v in stage.items() if k not in PERCEPTION and k != "wait")
    frames_cfg = runs[0].get("config", {}).get("frames", {})
    workers = frames_cfg.get("perception_workers", 1) if frames_cfg.get("prefetch", 0) else 1
    slowest = max(perception / workers, backend)  # the workers share the perception
    r = runs[0]
    data = {"fps": fps, "speedup": fps / base_fps, "stage_ms": stage, "frame_ms": frame_ms,
            "perception_ms": perception, "perception_workers": workers, "backend_ms": backend,
            "frame_over_slowest": frame_ms / slowest,
            "ate_sim3_cm": r["ate_sim3_cm"], "registered_share": r["registered_share"],
            "fragments": r.get("fragments"), "intra_edges": r.get("intra_edges")}
    text = (f"| {case.name} | {variant} | {fps:.2f} | {fps / base_fps:.2f}x | {frame_ms:.0f} | "
            + " | ".join(f"{stage[k]:.1f}" for k in STAGES)
            + f" | {perception:.0f} / {backend:.0f} | {workers} | {frame_ms / slowest:.2f} | {r['ate_sim3_cm']:.2f} | "
            f"{100 * r['registered_share']:.1f} | {r.get('intra_edges')} |")
    return text, data


@dataclass(frozen=True)
class Settings:
    """What slam_speed measures."""

    cases: tuple[str, ...] = tuple(CASES)  #: cases run: rgbd-128, rgbd-640x480, model-128, model-224
    #: this checkout's variants (after --baseline's run, when given): serial, prefetch, bounded, one-worker, after
    variants: tuple[str, ...] = tuple(VARIANTS)
    frames: int = 600  #: frames per sequence (model-224: half)
    repeats: int = 1  #: runs of each variant (alternating)
    threads: int | None = None  #: onnxruntime threads per model (none: each checkout's own default)
    #: the runs' --providers (model cases, this checkout), e.g. CUDAExecutionProvider,CPUExecutionProvider on
    #: a GPU (none: CPU)
    providers: str | None = None
    #: two ONNX files, DEPTH,DESCRIPTORS, this checkout's variants of the model cases run instead of the case's
    #: (e.g. int8 exports, benchmarks/protocols/lighter_models.py); the baseline keeps the case's (none: empty)
    models: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        check_not_empty(self, "cases", "variants")
        check_choices("cases", self.cases, CASES)
        check_choices("variants", self.variants, VARIANTS)
        if self.models and len(self.models) != 2:
            raise InputError(f"models: give two ONNX files, DEPTH,DESCRIPTORS (got {len(self.models)})")


CLI = ProtocolCli("slam_speed", Settings, __doc__, example="cases=rgbd-128")


def parse_args(argv: list[str] | None = None) -> tuple[argparse.Namespace, Settings]:
    """The plain options (baseline, work folder, report) and the settings of ``argv``."""
    ap = CLI.parser()
    ap.add_argument("--baseline", type=Path, help="checkout of the code before (run from its folder, its defaults)")
    ap.add_argument("--work", type=Path, default=WORK / "slam_speed", help=WORK_HELP)
    ap.add_argument("--report", type=Path, default=RESULTS / "slam_speed.md", help=REPORT_HELP)
    return CLI.parse(ap, argv)


def main(argv: list[str] | None = None) -> None:
    args, settings = parse_args(argv)
    rows, data = [], {}
    for name in settings.cases:
        case = CASES[name]
        seq = sequence(case, settings.frames // 2 if name == "model-224" else settings.frames, args.work)
        variants = ([BASELINE] if args.baseline else []) + list(settings.variants)
        runs: dict[str, list[dict]] = {v: [] for v in variants}
        for _ in range(settings.repeats):
            for v in variants:
                runs[v].append(run_once(case, v, seq, work=args.work, threads=settings.threads,
                                        baseline=args.baseline, providers=settings.providers,
                                        models=tuple(Path(m) for m in settings.models) if settings.models else None))
                print(f"{name} {v}: {runs[v][-1]['fps']:.2f} frames/s", flush=True)
        base = statistics.median(r["fps"] for r in runs[variants[0]])
        data[name] = {}
        for v in variants:
            text, data[name][v] = row(case, v, runs[v], base)
            rows.append(text)
    Report(__file__, "SLAM runtime speed: before vs after", argv).publish(
        args.report, body(settings, args.baseline, rows), settings, data, options=args)


def body(settings: Settings, baseline: Path | None, rows: list[str]) -> list[str]:
    return [
        f"- Machine: {os.cpu_count()} CPU cores ({platform.machine()}), no GPU, shared with other jobs; "
        f"onnxruntime {settings.threads or 'the default number of'} threads per model (the baseline's default: 2; "
        f"this checkout's: the cores less one); medians of {settings.repeats} run(s) per variant, the "
        "variants alternating.",
        "- Cases: " + "; ".join(f"{c}: {CASES[c].what}" for c in settings.cases)
        + f"; {settings.frames} frames (model-224: {settings.frames // 2}).",
        "- Variants: " + (f"baseline: {baseline} with its defaults; " if baseline else "")
        + "; ".join(f"{v}: {' '.join(VARIANTS[v]) or 'the defaults'}" for v in settings.variants)
        + " (the baseline, serial, prefetch and bounded are given ContraFeat's dense graph alone); coverage off."
        + (f" This checkout's variants run {settings.models[0]} and {settings.models[1]} in place of the case's models."
           if settings.models else ""),
        "- Columns: frames/s over the whole command's wall-clock time (summary.json's wall_seconds: opening "
        "the models, the frames, the final optimisation, fusion and the outputs) and "
        "its ratio to the first variant; ms per frame; ms per frame per stage (with perception ahead of the "
        "loop, io, depth and keypoints run in the workers beside the other stages, and wait is the time the "
        "loop waited for them); perception (io + depth + keypoints, summed over its threads) / back-end (the "
        "rest but wait) ms per frame; perception threads; frame time over the slower of perception / threads "
        "and the back-end; ATE Sim(3) RMSE (cm); registered share; intra-fragment edges.",
        "",
        "| case | variant | frames/s | vs first | ms/frame | " + " | ".join(STAGES)
        + " | perception / back-end ms | threads | frame / slowest | ATE cm | registered % | intra edges |",
        "|---|---|---|---|---|" + "---|" * len(STAGES) + "---|---|---|---|---|---|",
        *rows,
    ]


if __name__ == "__main__":
    main()
