"""The report's first step: :func:`collect` reads everything the report shows from the demo folder
and the finished stages' notes into one :class:`~c3f_demo.report_records.ReportData`: the metrics,
the environment, the unseen-surface estimates, the 3D view's data, the images earlier stages drew,
and what the figures are drawn from (depth samples, meshes, the tissue mask, per-frame labels).
It draws nothing and writes nothing. Lengths in metres."""

from __future__ import annotations

import importlib.metadata as md
import json
import os
import platform
import subprocess
from dataclasses import replace
from pathlib import Path

import numpy as np

from c3f_core.errors import InputError
from c3f_demo.context import REPO, DemoContext
from c3f_demo.report_records import DepthSamples, Image, ReportData, TissueSample, Video, ViewData
from c3f_demo.video import frame_log, run_metrics
from c3f_slam.io import Sequence

PACKAGES = ("c3fusion", "torch", "lightning", "onnxruntime", "open3d", "numpy", "opencv-python-headless")
#: the images each configuration's run folder holds for the report, per variant
RUN_IMAGES = {"demo": ("trajectory.png", "keyframe_graph.png"), "video": ("keyframe_graph.png",)}


def collect(ctx: DemoContext, done: dict | None = None) -> ReportData:
    """The report's data: the demo's, or on a user's video (``ctx.cfg.video``) the variant without
    ground truth. ``done``: ``notes`` of the finished stages and their ``timings``."""
    notes = (done or {}).get("notes", {})
    own = _video_fields(ctx, notes) if ctx.cfg.video else _demo_fields(ctx)
    slam = own["metrics"]["slam"]
    unseen, coverage, path_points = unseen_data(ctx, slam)
    images = {**own.pop("images"), **run_images(ctx, slam, RUN_IMAGES[own["variant"]]), **unseen_images(ctx, unseen)}
    return ReportData(
        config=ctx.cfg.as_dict(), environment=environment(ctx.cfg), zoo=zoo_models(notes),
        timings=[*(done or {}).get("timings", []), ("report", float("nan"), "this stage (running)")],
        ttt_guard=(notes.get("ttt_depth") or {}).get("guard"), unseen=unseen, coverage=coverage,
        path_points=path_points, images=images, meshes=run_meshes(ctx, slam), **own)


def _demo_fields(ctx: DemoContext) -> dict:
    """The demo's own part: the evaluate stage's metrics, the matches figure, the depth samples, the view."""
    metrics = {k: json.loads((ctx.root / "metrics" / f"{k}.json").read_text()) for k in ("slam", "depth", "matches")}
    return {"variant": "demo", "metrics": metrics, "view": view_data(ctx, metrics["slam"]),
            "images": {metrics["matches"]["figure"]: Image.read(ctx.root, metrics["matches"]["figure"])},
            "depth_samples": depth_samples(ctx.test_seq, depth_columns(ctx.models), ctx.cfg.report.sample_frames)}


def _video_fields(ctx: DemoContext, notes: dict) -> dict:
    """A user's video's own part: each run's numbers (:func:`c3f_demo.video.run_metrics`), the
    ingest record, the view stage's view, the tissue mask and the per-frame labels."""
    runs = notes.get("slam", {}).get("runs", {})
    slam = {name: run_metrics(ctx, name, runs.get(name, {"title": title, "status": "failed", "error": "not run"}))
            for name, (title, _) in ctx.slam_runs.items()}
    return {"variant": "video", "metrics": {"slam": slam}, "ingest": notes.get("ingest", {}), "images": {},
            "view": view_data(ctx, slam, (notes.get("view") or {}).get("views", {})),
            "tissue": tissue_sample(ctx, slam), "frame_labels": frame_labels(ctx, slam)}


def environment(cfg) -> dict:
    """Versions, machine and seeds for the report."""
    env = {"python": platform.python_version(), "machine": f"{platform.machine()}, {os.cpu_count()} CPU cores",
           "system": platform.platform()}
    for pkg in PACKAGES:
        try:
            env[pkg] = md.version(pkg)
        except md.PackageNotFoundError:
            pass
    try:
        env["git commit"] = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=REPO, capture_output=True,
                                           text=True, timeout=5).stdout.strip() or "unknown"
    except (OSError, subprocess.SubprocessError):
        env["git commit"] = "unknown"
    s = cfg.simulate
    env["seeds"] = (f"simulator {[seed for _, seed in s.train]} (train), {s.test[1]} (held-out); "
                    f"DepthNet {cfg.depth.seed}; ContraFeat {cfg.features.seed}" if s is not None
                    else f"DepthNet test-time training {cfg.ttt.seed}")
    return env


def zoo_models(notes: dict) -> dict:
    """The training stages' notes of the networks that came from the zoo."""
    return {k: notes[k] for k in ("train_depth", "train_features") if (notes.get(k) or {}).get("zoo")}


def ok_runs(ctx: DemoContext, slam: dict) -> list[str]:
    """The configurations that worked, in the demo's order."""
    return [n for n in ctx.slam_runs if slam.get(n, {}).get("status") == "ok"]


def read_mesh(path: Path):
    """The triangle mesh at ``path`` (None when there is no such file)."""
    import open3d as o3d

    return o3d.io.read_triangle_mesh(str(path)) if path.is_file() else None


def run_meshes(ctx: DemoContext, slam: dict) -> dict:
    """Each working configuration's ``mesh.ply`` (None where it wrote none)."""
    return {n: read_mesh(ctx.slam_dir(n) / "mesh.ply") for n, r in slam.items() if r.get("status") == "ok"}


def run_images(ctx: DemoContext, slam: dict, files: tuple[str, ...]) -> dict[str, Image]:
    """``slam/NAME/FILE`` of each working configuration, by path (missing ones included)."""
    paths = [f"slam/{n}/{f}" for n, r in slam.items() if r.get("status") == "ok" for f in files]
    return {p: Image.read(ctx.root, p) for p in paths}


def run_unseen(ctx: DemoContext, name: str, title: str) -> dict | None:
    """One configuration's own unseen-surface estimate (``coverage.json``, ``coverage_map.png``)
    beside the truth ``c3f_slam evaluate --gt`` measured for it; None when the run wrote none."""
    cov = ctx.slam_dir(name) / "coverage.json"
    if not cov.is_file():
        return None
    c = json.loads(cov.read_text())
    entry = {"run": title, "status": c.get("status"), "reason": c.get("reason"), "unseen_share": c.get("unseen_share"),
             "segments": c.get("segments", [])}
    if c.get("status") == "ok":
        entry["map"] = f"slam/{name}/coverage_map.png"
        ev_path = ctx.slam_dir(name) / "evaluation.json"
        truth = json.loads(ev_path.read_text()).get("unseen", {}) if ev_path.is_file() else {}
        if truth.get("status") == "ok":
            entry["truth"] = {"unseen_share": truth.get("truth"), "error_pp": truth.get("error_pp")}
            if truth.get("truth_map") and (ctx.slam_dir(name) / truth["truth_map"]).is_file():
                entry["truth_map"] = f"slam/{name}/{truth['truth_map']}"
    return entry


def unseen_data(ctx: DemoContext, slam: dict) -> tuple[dict, dict, np.ndarray | None]:
    """Every configuration's own unseen-surface estimate (:func:`run_unseen`) as ``source`` ``run``;
    where no run wrote one, ``ground_truth``: the runs with their seen share, their ``coverage.ply``
    (name -> mesh) and the true camera positions to crop it near. No truth on a user's video: {}."""
    ok = ok_runs(ctx, slam)
    estimates = [e for e in (run_unseen(ctx, n, slam[n]["title"]) for n in ok) if e is not None]
    if estimates:
        return {"source": "run", "runs": estimates}, {}, None
    seq = Sequence(ctx.test_seq)
    if not seq.has_poses:
        return {}, {}, None
    runs = [{"name": n, "run": slam[n]["title"], "seen_share": (slam[n].get("coverage") or {}).get("share")}
            for n in ok]
    meshes = {n: read_mesh(ctx.slam_dir(n) / "coverage.ply") for n in ok}
    return {"source": "ground_truth", "runs": runs}, meshes, seq.poses[:, :3, 3]


def unseen_images(ctx: DemoContext, unseen: dict) -> dict[str, Image]:
    """The estimated and true coverage maps the unseen-surface estimates name, by path."""
    paths = [r[k] for r in unseen.get("runs", []) for k in ("map", "truth_map") if r.get(k)]
    return {p: Image.read(ctx.root, p) for p in paths}


def view_data(ctx: DemoContext, slam: dict, views: dict[str, str | None] | None = None) -> ViewData | None:
    """The 3D view of the paper's configuration (else the first that worked): the viewer's data at
    the report's budget; ``views`` (run -> None or the error of the ``view`` stage's ``python -m
    c3f_slam view``): the view stage wrote it (its videos, or its error), else the report writes
    it. None when no configuration worked."""
    from c3f_slam.view.budget import REPORT_BUDGET
    from c3f_slam.view.page import view_data as viewer_data
    from c3f_slam.view.scene import run_layers

    ok = ok_runs(ctx, slam)
    if not ok:
        return None
    name = "paper" if "paper" in ok else ok[0]
    view = ViewData(name, slam[name]["title"], f"slam/{name}", write=views is None)
    error = None if views is None else views.get(name, "not run")
    if error is None:
        try:
            return replace(view, data=viewer_data(run_layers(ctx.slam_dir(name), REPORT_BUDGET)),
                           budget_triangles=REPORT_BUDGET.triangles,
                           videos=() if views is None else stage_videos(ctx, view.folder))
        except InputError as exc:
            error = str(exc)
    return replace(view, write=False, error=str(error))


def stage_videos(ctx: DemoContext, folder: str) -> tuple[Video, ...]:
    """The videos the view stage wrote into ``folder`` (relative to the demo folder)."""
    from c3f_slam.view.build import CAPTIONS, FLYTHROUGH, RERENDER

    return tuple(Video.read(ctx.root, f"{folder}/{v}", f"{v}: {CAPTIONS[v]}") for v in (RERENDER, FLYTHROUGH)
                 if (ctx.root / folder / v).is_file())


def depth_columns(models: Path) -> dict[str, Path]:
    """The depth networks of the sample figure: before and after test-time training when both
    were exported, else the one SLAM used."""
    before = models / "depthnet_pretrained" / "depthnet.onnx"
    if before.is_file():
        return {"before TTT": before, "after TTT": models / "depthnet" / "depthnet.onnx"}
    return {"predicted": models / "depthnet" / "depthnet.onnx"}


def depth_samples(seq_dir: Path, models: dict[str, Path], n: int) -> DepthSamples:
    """``n`` evenly spaced frames of the sequence with their true depth and each model's
    prediction (``models``: column label -> depth ONNX file), times the metric scale its export
    recorded (what ``c3f_slam run`` uses), when there is one."""
    from c3f_slam.models import DepthModel

    seq = Sequence(seq_dir)
    idx = np.linspace(0, len(seq) - 1, n).round().astype(int).tolist()
    rgbs = [seq.read_rgb(i) for i in idx]
    predicted, scales = {}, {}
    for label, path in models.items():
        model = DepthModel(path, threads=2)
        scales[label] = model.metric_scale or 1.0
        predicted[label] = [scales[label] * model.predict(im, seq.camera) for im in rgbs]
    return DepthSamples(idx, rgbs, [seq.read_depth(i) for i in idx], predicted, scales)


def tissue_sample(ctx: DemoContext, slam: dict) -> TissueSample | None:
    """The tissue mask of the first run that wrote one (``tissue_mask.png``, written before its
    first frame, so also by a run that failed later) with the middle frame of the sequence; None
    when no run wrote one."""
    import cv2

    for name in slam:
        path = ctx.slam_dir(name) / "tissue_mask.png"
        if path.is_file():
            seq = Sequence(ctx.test_seq)
            frame = len(seq) // 2
            return TissueSample(name, frame, seq.read_rgb(frame), cv2.imread(str(path), cv2.IMREAD_GRAYSCALE) > 127)
    return None


def frame_labels(ctx: DemoContext, slam: dict) -> dict[str, tuple[str, list[str]]]:
    """Per configuration, what became of its frames: (``timeline``, one label per frame of its
    ``frame_log.csv``) when the run wrote one, else (``counts``, the counts of summary.json as labels)."""
    out = {}
    for name, r in slam.items():
        labels = frame_log(ctx.slam_dir(name))
        kind = "timeline" if labels is not None else "counts"
        if labels is None:
            labels = [lab for lab, n in (r.get("frame_counts") or {}).items() for _ in range(n)]
        if labels:
            out[name] = (kind, labels)
    return out
