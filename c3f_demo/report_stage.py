"""The ``report`` stage: figures (depth samples, mesh renders, coverage), the environment, then
``DIR/report.html`` (:func:`c3f_demo.report.build_report`)."""

from __future__ import annotations

import importlib.metadata as md
import json
import os
import platform
import subprocess
from pathlib import Path

from c3f_demo.context import REPO, DemoContext
from c3f_demo.figures import depth_samples, mesh_renders
from c3f_demo.report import build_report
from c3f_demo.stages import Stage
from c3f_slam.errors import InputError
from c3f_slam.io import Sequence
from c3f_slam.io.atomic import atomic_write_text

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
                    f"DepthNet {cfg.depth.seed}; ContraFeat {cfg.features.seed}")
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
    for name in ok:
        renders = mesh_renders(ctx.slam_dir(name) / "coverage.ply", ctx.root / "figures" / f"coverage_{name}",
                               ctx.cfg.report.render_size, near=seq.poses[:, :3, 3])
        if renders:
            runs.append({"run": slam[name]["title"], "renders": renders,
                         "seen_share": (slam[name].get("coverage") or {}).get("share")})
    return {"source": "ground_truth", "runs": runs} if runs else {}


def view_entry(ctx: DemoContext, slam: dict) -> dict | None:
    """The 3D view of the paper's configuration (else the first that worked): ``slam/NAME/view.html``
    and its videos written by :func:`c3f_slam.view.build.write_view`, and the viewer's data at the
    report's budget; None when no configuration worked."""
    from c3f_slam.view.budget import REPORT_BUDGET
    from c3f_slam.view.build import CAPTIONS, write_view
    from c3f_slam.view.page import view_data
    from c3f_slam.view.scene import run_layers

    ok = [n for n in ctx.slam_runs if slam.get(n, {}).get("status") == "ok"]
    if not ok:
        return None
    name = "paper" if "paper" in ok else ok[0]
    entry = {"run": name, "title": slam[name]["title"]}
    try:
        res = write_view(ctx.slam_dir(name), progress=False)
    except InputError as exc:
        return {**entry, "error": str(exc)}
    entry["data"] = view_data(run_layers(ctx.slam_dir(name), REPORT_BUDGET))
    entry["budget_triangles"] = REPORT_BUDGET.triangles
    entry["videos"] = [(f"slam/{name}/{v}", f"{v}: {CAPTIONS[v]}") for v in res.videos]
    entry["render_ms"] = {v: r["ms_per_frame"] for v, r in res.videos.items()}
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
        timings = (done or {}).get("timings", [])
        metrics = {k: json.loads((ctx.root / "metrics" / f"{k}.json").read_text())
                   for k in ("slam", "depth", "matches")}
        figs = ctx.root / "figures"
        figures = {"depth": depth_samples(ctx.test_seq, depth_columns(ctx.models), ctx.cfg.report.sample_frames,
                                          figs / "depth_samples.png"),
                   "meshes": {n: mesh_renders(ctx.slam_dir(n) / "mesh.ply", figs / f"mesh_{n}",
                                              ctx.cfg.report.render_size)
                              for n, r in metrics["slam"].items() if r.get("status") == "ok"},
                   "unseen": unseen_figures(ctx, metrics["slam"])}
        notes = (done or {}).get("notes", {})
        models = {k: notes[k] for k in ("train_depth", "train_features") if (notes.get(k) or {}).get("zoo")}
        data = {"config": ctx.cfg.as_dict(), "metrics": metrics, "figures": figures,
                "timings": [*timings, ("report", float("nan"), "this stage (running)")],
                "environment": environment(ctx.cfg), "zoo": models, "ttt_guard": (notes.get("ttt_depth") or {}).get(
                    "guard"), "view": view_entry(ctx, metrics["slam"])}
        atomic_write_text(ctx.root / "report.html", build_report(ctx.root, data))
        return {"report": "report.html"}
