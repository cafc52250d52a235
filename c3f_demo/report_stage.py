"""The ``report`` stage: figures (depth samples, mesh renders, coverage), the environment, then
``DIR/report.html`` (:func:`c3f_demo.report.build_report`); :class:`VideoReport`, its variant on
a user's video (no ground truth)."""

from __future__ import annotations

import importlib.metadata as md
import json
import os
import platform
import subprocess
from pathlib import Path

from c3f_demo.context import REPO, DemoContext
from c3f_demo.figures import depth_samples, frame_strip, mask_overlay, mesh_renders
from c3f_demo.report import build_report
from c3f_demo.stages import Stage
from c3f_demo.video import frame_log, run_metrics
from c3f_slam.errors import InputError
from c3f_slam.io import Sequence
from c3f_slam.io.atomic import atomic_write_text
from c3f_slam.outputs import write_json

PACKAGES = ("c3fusion", "torch", "lightning", "onnxruntime", "open3d", "numpy", "opencv-python-headless")


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


def unseen_figures(ctx: DemoContext, slam: dict) -> dict:
    """Every configuration's own unseen-surface estimate (:func:`run_unseen`), or where no run wrote
    one, the ground-truth coverage from ``c3f_slam evaluate`` (coverage.ply rendered near the true path)."""
    ok = [n for n in ctx.slam_runs if slam.get(n, {}).get("status") == "ok"]
    estimates = [e for e in (run_unseen(ctx, n, slam[n]["title"]) for n in ok) if e is not None]
    if estimates:
        return {"source": "run", "runs": estimates}
    seq, runs = Sequence(ctx.test_seq), []
    if not seq.has_poses:  # a user's video: no truth to fall back on
        return {}
    for name in ok:
        renders = mesh_renders(ctx.slam_dir(name) / "coverage.ply", ctx.root / "figures" / f"coverage_{name}",
                               ctx.cfg.report.render_size, near=seq.poses[:, :3, 3])
        if renders:
            runs.append({"run": slam[name]["title"], "renders": renders,
                         "seen_share": (slam[name].get("coverage") or {}).get("share")})
    return {"source": "ground_truth", "runs": runs} if runs else {}


def view_entry(ctx: DemoContext, slam: dict, views: dict[str, str | None] | None = None) -> dict | None:
    """The 3D view of the paper's configuration (else the first that worked): ``slam/NAME/view.html``
    and its videos, written here by :func:`c3f_slam.view.build.write_view` or, given ``views`` (run
    -> None or the error of the ``view`` stage's ``python -m c3f_slam view``), as that stage wrote
    them; and the viewer's data at the report's budget. None when no configuration worked."""
    from c3f_slam.view.budget import REPORT_BUDGET
    from c3f_slam.view.build import CAPTIONS, FLYTHROUGH, RERENDER, write_view
    from c3f_slam.view.page import view_data
    from c3f_slam.view.scene import run_layers

    ok = [n for n in ctx.slam_runs if slam.get(n, {}).get("status") == "ok"]
    if not ok:
        return None
    name = "paper" if "paper" in ok else ok[0]
    entry = {"run": name, "title": slam[name]["title"]}
    try:
        if views is None:
            videos = write_view(ctx.slam_dir(name), progress=False).videos
        elif views.get(name, "not run") is not None:
            raise InputError(views.get(name, "not run"))
        else:
            videos = {v: {} for v in (RERENDER, FLYTHROUGH) if (ctx.slam_dir(name) / v).is_file()}
    except InputError as exc:
        return {**entry, "error": str(exc)}
    entry["data"] = view_data(run_layers(ctx.slam_dir(name), REPORT_BUDGET))
    entry["budget_triangles"] = REPORT_BUDGET.triangles
    entry["videos"] = [(f"slam/{name}/{v}", f"{v}: {CAPTIONS[v]}") for v in videos]
    entry["render_ms"] = {v: r["ms_per_frame"] for v, r in videos.items() if "ms_per_frame" in r}
    return entry


def depth_columns(models: Path) -> dict[str, Path]:
    """The depth networks of the sample figure: before and after test-time training when both
    were exported, else the one SLAM used."""
    before = models / "depthnet_pretrained" / "depthnet.onnx"
    if before.is_file():
        return {"before TTT": before, "after TTT": models / "depthnet" / "depthnet.onnx"}
    return {"predicted": models / "depthnet" / "depthnet.onnx"}


class Report(Stage):
    """Figures and ``DIR/report.html``."""

    name = "report"
    upstream = ("evaluate",)

    def settings(self, cfg):
        return {"sample_frames": cfg.report.sample_frames, "render_size": cfg.report.render_size}

    def outputs(self, ctx):
        return [ctx.root / "report.html"]

    def estimate_s(self, cfg):
        return 40.0  # figures, and the 3D view's videos (about 45 ms per rendered frame)

    def run(self, ctx, done=None):
        metrics = {k: json.loads((ctx.root / "metrics" / f"{k}.json").read_text())
                   for k in ("slam", "depth", "matches")}
        figs = ctx.root / "figures"
        figures = {"depth": depth_samples(ctx.test_seq, depth_columns(ctx.models), ctx.cfg.report.sample_frames,
                                          figs / "depth_samples.png"),
                   "meshes": mesh_figures(ctx, metrics["slam"]), "unseen": unseen_figures(ctx, metrics["slam"])}
        data = report_data(ctx, done, metrics, figures)
        atomic_write_text(ctx.root / "report.html", build_report(ctx.root, data))
        return {"report": "report.html"}


def mesh_figures(ctx: DemoContext, slam: dict) -> dict[str, list[str]]:
    """Renders of each configuration's mesh that worked (:func:`mesh_renders`), by configuration."""
    return {n: mesh_renders(ctx.slam_dir(n) / "mesh.ply", ctx.root / "figures" / f"mesh_{n}",
                            ctx.cfg.report.render_size)
            for n, r in slam.items() if r.get("status") == "ok"}


def report_data(ctx: DemoContext, done: dict | None, metrics: dict, figures: dict,
                views: dict[str, str | None] | None = None) -> dict:
    """The inputs of :func:`build_report` the demo and the video report share: settings, metrics,
    figures, the time per stage, environment, zoo models, what the test-time training guard did,
    the 3D view (:func:`view_entry`)."""
    notes = (done or {}).get("notes", {})
    models = {k: notes[k] for k in ("train_depth", "train_features") if (notes.get(k) or {}).get("zoo")}
    return {"config": ctx.cfg.as_dict(), "metrics": metrics, "figures": figures,
            "timings": [*(done or {}).get("timings", []), ("report", float("nan"), "this stage (running)")],
            "environment": environment(ctx.cfg), "zoo": models,
            "ttt_guard": (notes.get("ttt_depth") or {}).get("guard"), "view": view_entry(ctx, metrics["slam"], views)}


def tissue_figure(ctx: DemoContext, slam: dict) -> dict | None:
    """The tissue mask of the first run that wrote one (``tissue_mask.png``, written before its first
    frame, so also by a run that failed later) drawn over the middle frame of the sequence
    (:func:`mask_overlay`); None when no run wrote one."""
    import cv2

    for name in slam:
        path = ctx.slam_dir(name) / "tissue_mask.png"
        if path.is_file():
            seq = Sequence(ctx.test_seq)
            mask = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE) > 127
            frame = len(seq) // 2
            return {"run": name, "frame": frame,
                    "figure": mask_overlay(seq.read_rgb(frame), mask, ctx.root / "figures" / "tissue_mask.png")}
    return None


def frame_figures(ctx: DemoContext, slam: dict) -> dict[str, dict]:
    """Per configuration, the strip of what became of its frames: the timeline of its
    ``frame_log.csv`` when the run wrote one, else the counts (summary.json) grouped."""
    out = {}
    for name, r in slam.items():
        labels = frame_log(ctx.slam_dir(name))
        kind = "timeline" if labels is not None else "counts"
        if labels is None:
            labels = [lab for lab, n in (r.get("frame_counts") or {}).items() for _ in range(n)]
        if labels:
            out[name] = {"kind": kind, **frame_strip(labels, ctx.root / "figures" / f"frames_{name}.png")}
    return out


class VideoReport(Report):
    """``DIR/report.html`` of a user's video: the demo's report without its ground-truth sections
    (:func:`c3f_demo.report.build_report`, variant ``video``), with the tissue mask, the frames per
    cause, the registered share and the jitter ratio of each run (``metrics/slam.json``)."""

    upstream = ("view",)

    def run(self, ctx, done=None):
        notes = (done or {}).get("notes", {})
        runs = notes.get("slam", {}).get("runs", {})
        slam = {name: run_metrics(ctx, name, runs.get(name, {"title": title, "status": "failed", "error": "not run"}))
                for name, (title, _) in ctx.slam_runs.items()}
        write_json(ctx.root / "metrics" / "slam.json", slam)
        figures = {"meshes": mesh_figures(ctx, slam), "unseen": unseen_figures(ctx, slam),
                   "tissue": tissue_figure(ctx, slam), "frames": frame_figures(ctx, slam)}
        data = report_data(ctx, done, {"slam": slam}, figures, (notes.get("view") or {}).get("views", {}))
        data["ingest"] = notes.get("ingest", {})
        atomic_write_text(ctx.root / "report.html", build_report(ctx.root, data, variant="video"))
        return {"report": "report.html"}
