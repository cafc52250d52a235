"""The demo (``python -m c3f_demo``): the report writer on tiny fake inputs, the report's one-way
steps, the resume / refuse / Ctrl-C logic of the runner on fake stages, and (slow) the whole
``--quick`` pipeline."""

from __future__ import annotations

import base64
import inspect
import json
import math
import re
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest

from c3f_core.errors import InputError
from c3f_demo import config as demo_cfg
from c3f_demo import report_stage, runner
from c3f_demo.context import DemoContext
from c3f_demo.progress import clock, read_step_fraction, time_table
from c3f_demo.report import SECTIONS, build_report
from c3f_demo.report_records import Figures, Image, ReportData, Video, ViewData, ViewFigures
from c3f_demo.stages import Stage
from c3f_demo.state import DemoState, stage_key
from tests.bad_input import default_sigint
from tests.startup import packages_loaded_by

ROOT = Path(__file__).resolve().parents[1]


def embedded_images(html: str) -> list[np.ndarray]:
    """Every data-URI PNG of the page, decoded (None where it does not decode)."""
    return [cv2.imdecode(np.frombuffer(base64.b64decode(b), np.uint8), cv2.IMREAD_COLOR)
            for b in re.findall(r'src="data:image/png;base64,([^"]+)"', html)]


def png_bytes(value: int = 128) -> bytes:
    """An 8x12 grey PNG."""
    return cv2.imencode(".png", np.full((8, 12, 3), value, np.uint8))[1].tobytes()


def fake_report_inputs() -> tuple[ReportData, Figures]:
    """The data and figures as the collect and figures steps give them, in memory (no file):
    one configuration ok, one failed."""
    images = {p: Image(p, png_bytes()) for p in (
        "figures/depth_samples.png", "figures/matches.png", "figures/mesh_gt_sift_side.png",
        "figures/coverage_gt_sift_side.png", "slam/gt_sift/trajectory.png", "slam/gt_sift/keyframe_graph.png")}
    depth = {k: 0.1 for k in ("abs_rel", "sq_rel", "rmse", "rmse_log", "a1", "a2", "a3")}
    slam = {"gt_sift": {"title": "ground-truth depth + SIFT", "status": "ok", "ate_sim3_m": 0.0012,
                        "gt_length_m": 0.05, "registered_share": 0.9, "coverage": {"share": 0.1}},
            "paper": {"title": "predicted depth + ContraFeat", "status": "failed",
                      "error": "error: no frame could be registered (exit 2)"}}
    match = {"found": 10, "correct": 7, "precision": 0.7, "recall": 0.5, "near_misses": 1}
    metrics = {"slam": slam, "depth": {"frames": [0, 2], "median_scaled": {**depth, "scale": 1.0}, "metric": depth},
               "matches": {"pair": [3, 7], "keypoints": [40, 42], "ground_truth": 20, "sift": match,
                           "contrafeat": match, "figure": "figures/matches.png"}}
    data = ReportData("demo", demo_cfg.demo_config(quick=True).as_dict(), metrics, [("simulate", 3.0, "ran")],
                      {"python": "3.11", "seeds": "1, 2"}, unseen={"source": "ground_truth", "runs": [
                          {"name": "gt_sift", "run": "ground-truth depth + SIFT", "seen_share": 0.1}]})
    figs = Figures(images=images, depth={"range_m": [0.01, 0.09]}, meshes={"gt_sift": ["mesh_gt_sift_side.png"]},
                   coverage={"gt_sift": ["coverage_gt_sift_side.png"]})
    return data, figs


def test_report_writer_on_fake_inputs():
    """Every section is present, every image is embedded and decodes, a failed configuration is
    said plainly with no number, the ground-truth coverage is labelled as such, nothing is linked."""
    html = build_report(*fake_report_inputs())
    for sid in SECTIONS:
        assert f'<section id="{sid}">' in html, sid
    images = embedded_images(html)
    assert len(images) == 6 and all(im is not None and im.shape == (8, 12, 3) for im in images)
    assert "FAILED" in html and "no frame could be registered" in html
    assert "0.12" in html  # 1.2 mm ATE in cm
    assert "<b>Ground truth</b>" in html and "supervised depth term" in html
    assert "http" not in html and "<script" not in html


@pytest.mark.e2e
def test_report_embeds_the_3d_view_and_videos(tmp_path):
    """The report with a real run's 3D view and an embedded video: one file with nothing to fetch;
    in headless Chromium with the network off it draws, every layer toggles, the video decodes."""
    from c3f_slam.cli.main import main as slam_main
    from c3f_slam.view.budget import REPORT_BUDGET
    from c3f_slam.view.page import view_data
    from c3f_slam.view.scene import run_layers
    from c3f_slam.view.video import write_mp4
    from datamodules.synthetic.fixture import make_tiny_sequence
    from tests import browser

    seq = make_tiny_sequence(tmp_path / "seq", frames=8, size=128, seed=3)
    run = tmp_path / "slam" / "gt_sift"
    assert slam_main(["run", str(seq), "--out", str(run), "--set", "fragments.min_correspondences=15", "--quiet"]) == 0
    write_mp4(run / "rerender.mp4", [np.full((64, 96, 3), 20 * i, np.uint8) for i in range(10)])
    data, figs = fake_report_inputs()
    data = replace(data, view=ViewData("gt_sift", "ground-truth depth + SIFT", "slam/gt_sift", False, view_data(
        run_layers(run, REPORT_BUDGET)), REPORT_BUDGET.triangles))
    figs = replace(figs, view=ViewFigures((Video.read(tmp_path, "slam/gt_sift/rerender.mp4", "rerender.mp4"),),
                                          {"rerender.mp4": 12.0}))
    report = tmp_path / "report.html"
    report.write_text(build_report(data, figs))
    html = report.read_text()
    assert 'class="c3f-view"' in html and "data:video/mp4;base64," in html
    assert not re.search(r'(src|href)="https?:', html)
    res = browser.selftest(report)
    assert res["errors"] == [] and len(res["views"]) == 1
    view = res["views"][0]
    assert view["drawn"] > 0 and {"surface", "unseen", "path", "keyframes"} <= set(view["layers"])
    assert all(r["changed"] > 0 and r["restored"] for r in view["layers"].values()), view["layers"]
    assert [(v["width"], v["height"], v["error"]) for v in res["videos"]] == [(96, 64, None)]


def test_report_says_missing_image_and_run_coverage():
    data, figs = fake_report_inputs()
    del figs.images["figures/matches.png"]
    figs.images["slam/gt_sift/coverage_map.png"] = Image("slam/gt_sift/coverage_map.png", png_bytes())
    data = replace(data, unseen={"source": "run", "runs": [
        {"run": "x", "status": "ok", "unseen_share": 0.25, "map": "slam/gt_sift/coverage_map.png",
         "truth": {"unseen_share": 0.27, "error_pp": -2.0},
         "segments": [{"start_m": 0.0, "end_m": 0.02, "unseen_share": 0.5}]},
        {"run": "y", "status": "unavailable", "reason": "the camera moved less than 1.0 cm forward"}]})
    html = build_report(data, figs)
    assert "missing image: matches.png" in html and "<b>Ground truth</b>" not in html
    assert "<b>25.0 %</b> unseen (truth 27.0 %, error -2.0 pp)" in html
    assert "y: no estimate (the camera moved less than 1.0 cm forward)" in html
    data.metrics["slam"]["odometry"] = {**data.metrics["slam"]["gt_sift"], "title": "odometry"}
    html = build_report(data, figs)
    assert "No keyframe graph: frame-to-frame odometry" in html and "missing image: keyframe_graph.png" not in html


def test_report_without_coverage_renders_says_so():
    """Ground truth to compare with, but no coverage render drawn: the plain note, no empty section."""
    data, figs = fake_report_inputs()
    html = build_report(data, replace(figs, coverage={"gt_sift": []}))
    assert "No configuration gave a reconstruction to measure coverage with." in html
    assert "<b>Ground truth</b>" not in html


def test_report_shows_depth_before_and_after_test_time_training():
    data, figs = fake_report_inputs()
    d = data.metrics["depth"]
    before = {k: 0.3 for k in ("abs_rel", "sq_rel", "rmse", "rmse_log", "a1", "a2", "a3")}
    d["before_ttt"] = {"median_scaled": {**before, "scale": 1.0}, "metric": before}
    html = build_report(data, figs)
    assert "before TTT, median scaling" in html and "after TTT, metric" in html and "0.300" in html
    assert "Test-time training lowered the error</b>: Abs Rel 0.300 -> 0.100" in html
    d["before_ttt"]["median_scaled"]["abs_rel"] = 0.1009
    assert "Test-time training left the error unchanged (within 1 %)</b>" in build_report(data, figs)
    assert "test-time trained on the held-out sequence" in html
    data.config["ttt"]["steps"] = 0
    del d["before_ttt"]
    html = build_report(data, figs)
    assert "before TTT" not in html and "No test-time training" in html


#: the report's three steps and the modules of each: collect -> figures -> HTML
REPORT_STEPS = {"collect": ("c3f_demo.collect",), "figures": ("c3f_demo.figures",),
                "html": ("c3f_demo.report", "c3f_demo.html")}


def test_report_steps_import_no_other_step():
    """One way: no step module imports another step's module (or the stage that runs them); they
    share only the records (c3f_demo.report_records), which import no step."""
    from tests.test_import_boundary import _imports

    stage = ("c3f_demo.report_stage",)
    for step, modules in {**REPORT_STEPS, "records": ("c3f_demo.report_records",)}.items():
        others = [m for s, ms in REPORT_STEPS.items() if s != step for m in ms] + list(stage)
        for module in modules:
            path = ROOT / (module.replace(".", "/") + ".py")
            bad = sorted({m for _, m in _imports(path) if any(m == o or m.startswith(o + ".") for o in others)})
            assert bad == [], f"{module} ({step}) imports {bad}"


def test_html_step_reads_no_file(monkeypatch):
    """``build_report`` is a function of the data and the figures alone: it takes no path and
    touches no file."""
    def refuse(*args, **kwargs):
        raise AssertionError("the HTML step touched a file")

    assert [p.annotation for p in inspect.signature(build_report).parameters.values()] == ["ReportData", "Figures"]
    data, figs = fake_report_inputs()
    for name in ("read_bytes", "read_text", "is_file", "exists", "stat", "open"):
        monkeypatch.setattr(Path, name, refuse)
    monkeypatch.setattr("builtins.open", refuse)
    assert '<section id="summary">' in build_report(data, figs)


def test_report_stage_runs_collect_then_figures_then_html_once(tmp_path, monkeypatch):
    """The stage calls each step once, in order, and hands each step's result to the next."""
    calls = []
    data, figs = fake_report_inputs()

    def step(name, result):
        def run(*args):
            calls.append((name, args))
            return result
        return run

    monkeypatch.setattr(report_stage, "collect", step("collect", data))
    monkeypatch.setattr(report_stage, "make_figures", step("figures", figs))
    monkeypatch.setattr(report_stage, "build_report", step("html", "<html></html>"))
    ctx = DemoContext(tmp_path, demo_cfg.demo_config(quick=True))
    assert report_stage.Report().run(ctx, {"notes": {}}) == {"report": "report.html"}
    assert [name for name, _ in calls] == ["collect", "figures", "html"]
    assert calls[1][1] == (data, tmp_path) and calls[2][1] == (data, figs)
    assert (tmp_path / "report.html").read_text() == "<html></html>"


class FakeStage(Stage):
    def __init__(self, name, upstream=(), value=1, interrupt=False):
        self.name, self.upstream, self.value, self.interrupt, self.calls = name, upstream, value, interrupt, 0

    def settings(self, cfg):
        return {"value": self.value}

    def outputs(self, ctx):
        return [ctx.root / f"{self.name}.txt"]

    def run(self, ctx, done=None):
        self.calls += 1
        if self.interrupt:
            raise KeyboardInterrupt
        (ctx.root / f"{self.name}.txt").write_text("x")
        return {"n": self.calls}


def test_runner_resumes_refuses_and_stops_on_ctrl_c(tmp_path, monkeypatch, capsys):
    a, b = FakeStage("a"), FakeStage("b", ("a",))
    monkeypatch.setattr(runner, "STAGES", (a, b))
    cfg = demo_cfg.demo_config(quick=True)
    rows = runner.run_demo(tmp_path / "d", cfg)
    assert [r[2] for r in rows] == ["ran", "ran"] and (a.calls, b.calls) == (1, 1)
    rows = runner.run_demo(tmp_path / "d", cfg)  # same settings: both skipped
    assert all(r[2].startswith("skipped") for r in rows) and (a.calls, b.calls) == (1, 1)
    a.value = 2  # a's settings changed: refused, nothing rerun
    with pytest.raises(InputError, match="stage a was made with other settings"):
        runner.run_demo(tmp_path / "d", cfg)
    assert (a.calls, b.calls) == (1, 1)
    runner.run_demo(tmp_path / "d", cfg, overwrite=True)  # redo a and (its key changed) b
    assert (a.calls, b.calls) == (2, 2)
    b.interrupt, b.value = True, 5
    with pytest.raises(runner.DemoInterrupted, match="interrupted in stage b"):
        runner.run_demo(tmp_path / "d", cfg, overwrite=True)
    state = DemoState(tmp_path / "d")
    assert list(state.stages) == ["a"]  # b forgotten, a kept
    assert "total" in capsys.readouterr().out


def test_runner_new_stage_in_the_middle_reruns_what_reads_from_it(tmp_path, monkeypatch):
    """A folder made before a stage was added: the new stage runs, the later stages that read from
    it rerun, a later one that does not stays done, and every record is kept (whatever their order
    in the state file)."""
    a, c, d = FakeStage("a"), FakeStage("c", ("a",)), FakeStage("d", ("a",))
    monkeypatch.setattr(runner, "STAGES", (a, c, d))
    cfg = demo_cfg.demo_config(quick=True)
    runner.run_demo(tmp_path / "d", cfg)
    b, c2 = FakeStage("b", ("a",)), FakeStage("c", ("a", "b"))
    monkeypatch.setattr(runner, "STAGES", (a, b, c2, d))
    assert runner.downstream("b") == ["b", "c"] and runner.downstream("a") == ["a", "b", "c", "d"]
    rows = runner.run_demo(tmp_path / "d", cfg, overwrite=True)
    assert [r[2][:7] for r in rows] == ["skipped", "ran", "ran", "skipped"]
    assert (a.calls, b.calls, c2.calls, d.calls) == (1, 1, 1, 1)
    assert sorted(DemoState(tmp_path / "d").stages) == ["a", "b", "c", "d"]
    rows = runner.run_demo(tmp_path / "d", cfg)
    assert all(r[2].startswith("skipped") for r in rows)


def test_run_many_logs_each_command_and_returns_failures(tmp_path):
    from c3f_demo.context import DemoContext, StageFailed

    ctx = DemoContext(tmp_path, demo_cfg.demo_config(quick=True))
    out = ctx.run_many("stage", {"ok": ["-c", "print('fine')"],
                                 "bad": ["-c", "import sys; print('error: broken input'); sys.exit(3)"]})
    assert out["ok"] is None and isinstance(out["bad"], StageFailed)
    assert "error: broken input (exit 3; log:" in str(out["bad"])
    assert "fine" in ctx.log("stage_ok").read_text() and "broken" in ctx.log("stage_bad").read_text()


def _interrupted_demo(tmp_path, monkeypatch, polls: int = 20):
    """A quick demo context whose run_many gets Ctrl-C at its ``polls``-th pause (after ~1 s);
    only run_many's own pause is replaced: time.sleep itself is shared with other threads."""
    from c3f_demo import context

    calls, real_pause = [], context.poll_pause

    def interrupt_soon():
        calls.append(1)
        if len(calls) == polls:
            raise KeyboardInterrupt
        real_pause()

    monkeypatch.setattr(context, "poll_pause", interrupt_soon)
    return context.DemoContext(tmp_path, demo_cfg.demo_config(quick=True))


def test_run_many_on_ctrl_c_stops_the_running_and_starts_no_more(tmp_path, monkeypatch):
    from c3f_demo import context

    ctx = _interrupted_demo(tmp_path, monkeypatch)
    monkeypatch.setattr(context, "parallel_jobs", lambda: 2)
    slow = ["-c", "import time; print('started', flush=True); time.sleep(60); print('fin' + 'ished', flush=True)"]
    with pytest.raises(KeyboardInterrupt):
        ctx.run_many("s", {"a": slow, "b": slow, "c": ["-c", "print('c')"]})
    assert ctx.log("s_a").is_file() and ctx.log("s_b").is_file() and not ctx.log("s_c").exists()
    for name in ("s_a", "s_b"):  # the sleeping children were stopped, not waited out
        assert "finished" not in ctx.log(name).read_text()


def test_run_many_kills_a_command_that_ignores_ctrl_c(tmp_path, monkeypatch):
    from c3f_demo import context

    ctx = _interrupted_demo(tmp_path, monkeypatch)
    monkeypatch.setattr(context, "INTERRUPT_GRACE_S", 1.0)
    deaf = ["-c", "import signal, time; signal.signal(signal.SIGINT, signal.SIG_IGN); print('started', flush=True); "
                  "time.sleep(60); print('fin' + 'ished', flush=True)"]
    with pytest.raises(KeyboardInterrupt):
        ctx.run_many("s", {"a": deaf})
    assert "finished" not in ctx.log("s_a").read_text()  # killed after the grace, not waited out


def test_state_refuses_a_folder_that_is_no_demo(tmp_path):
    (tmp_path / "x.txt").write_text("mine")
    with pytest.raises(InputError, match="not a demo folder"):
        DemoState(tmp_path)
    assert stage_key({"a": 1}, []) != stage_key({"a": 2}, []) != stage_key({"a": 1}, ["k"])


def test_progress_helpers(tmp_path):
    assert clock(75) == "1:15" and clock(3725) == "1:02:05"
    p = tmp_path / "p.txt"
    assert read_step_fraction(p) is None
    p.write_text("5 20\n")
    assert read_step_fraction(p) == 0.25
    assert "total" in time_table([("a", 1.0, "ran"), ("b", 2.0, "ran")])


@pytest.mark.e2e
@pytest.mark.parametrize("command", [["c3f_demo"], ["c3f_models", "demo"]])  # the old spelling stays one release
def test_cli_bad_out_is_one_line(tmp_path, command):
    (tmp_path / "file").write_text("x")
    r = subprocess.run([sys.executable, "-m", *command, "--out", str(tmp_path / "file"), "--quick"],
                       cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and r.stderr.strip().count("\n") == 0 and r.stderr.startswith("error: --out")


#: the two ways the demo starts: from the zoo's models (the default) and training them first
MODES = {"zoo": [], "from_scratch": ["--from-scratch"]}


@pytest.fixture(scope="module", params=list(MODES))
def quick_demo(request, tmp_path_factory) -> tuple[Path, subprocess.CompletedProcess, list[str]]:
    """``python -m c3f_demo --quick [--from-scratch]`` into a fresh folder (the whole
    pipeline, a few minutes)."""
    out = tmp_path_factory.mktemp("demo") / "out"
    args = ["--quick", *MODES[request.param]]
    r = subprocess.run([sys.executable, "-m", "c3f_demo", "--out", str(out), *args], cwd=ROOT,
                       capture_output=True, text=True, timeout=1800)
    return out, r, args


@pytest.mark.e2e
@pytest.mark.long
def test_quick_demo_end_to_end(quick_demo):
    """Files and metrics of a --quick run: every configuration either ok with a finite ATE below the
    path length or said failed; the RGB-D reference works; the report has every section and every
    embedded image decodes; every stage reported a time. Then a rerun skips every stage and other
    settings are refused (one test per mode, so that pytest-xdist runs each demo once)."""
    out, r, args = quick_demo
    assert r.returncode == 0, r.stderr[-2000:]
    from_zoo = "--from-scratch" not in args
    trained = [] if from_zoo else ["runs/depthnet/tb/version_0/checkpoints/last.ckpt",
                                   "runs/contrafeat/tb/version_0/checkpoints/last.ckpt"]
    for f in ("report.html", "demo_state.json", "models/depthnet/depthnet.onnx", "models/contrafeat/contrafeat.onnx",
              *trained, "runs/depthnet_ttt/tb/version_0/checkpoints/last.ckpt",
              "runs/depthnet_ttt/tb/version_0/checkpoints/guard.json",  # test-time training ran under its guard
              "models/depthnet_pretrained/depthnet.onnx", "slam/gt_sift/trajectory.txt",
              "slam/gt_sift/mesh.ply", "metrics/depth.json", "metrics/matches.json", "figures/matches.png",
              "figures/depth_samples.png"):
        assert (out / f).is_file(), f
    if from_zoo:  # the zoo's files as they are, the tuned network with the zoo model's metric scale
        from c3f_slam.models import zoo
        from c3f_slam.models.nets import DepthModel

        entry = zoo.entry(demo_cfg.ZooModels().depth)
        assert (out / "models/depthnet_pretrained/depthnet.onnx").read_bytes() == entry.file_for(
            "depth", "test").read_bytes()
        scale = DepthModel(out / "models/depthnet/depthnet.onnx").metric_scale
        assert scale == pytest.approx(DepthModel(entry.file_for("depth", "test")).metric_scale)
        assert "zoo:" + entry.name in (out / "report.html").read_text()
    slam = json.loads((out / "metrics" / "slam.json").read_text())
    assert slam["gt_sift"]["status"] == "ok"
    for name, res in slam.items():
        if res["status"] == "ok":
            assert math.isfinite(res["ate_sim3_m"]) and res["ate_sim3_m"] < res["gt_length_m"], (name, res)
        else:
            assert res["error"], name
    depth = json.loads((out / "metrics" / "depth.json").read_text())
    for metrics in (depth, depth["before_ttt"]):  # after and before test-time training
        assert all(math.isfinite(metrics["median_scaled"][k]) for k in ("abs_rel", "sq_rel", "rmse", "a1"))
    assert depth["median_scaled"] != depth["before_ttt"]["median_scaled"]  # the tuned network differs
    html = (out / "report.html").read_text()
    for sid in SECTIONS:
        assert f'<section id="{sid}">' in html, sid
    images = embedded_images(html)
    assert len(images) >= 8 and all(im is not None and im.size > 0 for im in images)
    viewed = "paper" if slam["paper"]["status"] == "ok" else next(n for n, v in slam.items() if v["status"] == "ok")
    for f in ("view.html", "rerender.mp4", "flythrough.mp4"):  # the 3D view of one configuration
        assert (out / "slam" / viewed / f).is_file(), f
    assert 'class="c3f-view"' in html and html.count("data:video/mp4;base64,") == 2
    state = json.loads((out / "demo_state.json").read_text())
    assert list(state["stages"]) == [s.name for s in runner.STAGES]
    assert "total" in r.stdout and "report:" in r.stdout
    _check_rerun_skips_and_other_settings_refused(out, args)


def _check_rerun_skips_and_other_settings_refused(out: Path, args: list[str]) -> None:
    again = subprocess.run([sys.executable, "-m", "c3f_demo", "--out", str(out), *args], cwd=ROOT,
                           capture_output=True, text=True, timeout=300)
    assert again.returncode == 0 and again.stdout.count("skipped: done earlier") == len(runner.STAGES)
    other_args = [a for a in args if a != "--quick"]
    other = subprocess.run([sys.executable, "-m", "c3f_demo", "--out", str(out), *other_args], cwd=ROOT,
                           capture_output=True, text=True, timeout=300)
    assert other.returncode == 2 and other.stderr.count("\n") == 1 and "other settings" in other.stderr


@pytest.mark.slow
@pytest.mark.parametrize("sig", ["SIGINT", "SIGTERM"])
def test_ctrl_c_is_one_line_and_keeps_finished_stages(tmp_path, sig):
    """SIGINT to the demo's process group (a terminal's Ctrl-C), or SIGTERM, during training:
    exit 130, one line, the simulate stage stays recorded, the fit saved its interrupt checkpoint."""
    import os
    import signal
    import time

    out = tmp_path / "out"
    p = subprocess.Popen([sys.executable, "-m", "c3f_demo", "--out", str(out), "--quick", "--from-scratch"],
                         cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True,
                         preexec_fn=default_sigint)
    t0 = time.time()
    while not (out / "logs" / "train_depth.log").exists() and time.time() - t0 < 300:
        time.sleep(0.5)
    time.sleep(10)
    os.killpg(p.pid, getattr(signal, sig))
    _, err = p.communicate(timeout=300)
    assert p.returncode == 130 and err.count("\n") == 1 and "interrupted in stage train_depth" in err
    assert list(json.loads((out / "demo_state.json").read_text())["stages"]) == ["simulate"]
    assert list(out.glob("runs/depthnet/tb/version_0/checkpoints/interrupted.ckpt"))


def test_the_demo_process_starts_without_the_training_stack(tmp_path):
    """``python -m c3f_demo --help`` imports none of torch, Lightning, Open3D, OpenCV, onnxruntime;
    the demo's own process (runner, every stage: here stopped by a bad ``--out``) neither torch nor
    Lightning: its ``fit`` and ``export`` subprocesses load them (the training callback too,
    :mod:`c3f_demo.progress_callback`)."""
    heavy = {"torch", "lightning", "open3d", "cv2", "onnxruntime"}
    loaded = packages_loaded_by("c3f_demo", "--help")
    assert "c3f_demo" in loaded and not loaded & heavy, sorted(loaded & heavy)
    (tmp_path / "file").write_text("")
    loaded = packages_loaded_by("c3f_demo", "--out", str(tmp_path / "file"), status=2)
    assert {"open3d", "cv2"} <= loaded  # the stages were imported
    assert not loaded & {"torch", "lightning"}, sorted(loaded & heavy)


def test_progress_callback_of_the_fit_config_writes_what_the_eta_reads(tmp_path):
    """The callback class path of the demo's ``fit`` configs loads, and its file gives the fraction."""
    import importlib
    from types import SimpleNamespace

    import yaml

    from c3f_demo.context import DemoContext
    from c3f_demo.stages import _fit_yaml

    ctx = DemoContext(tmp_path, demo_cfg.demo_config(quick=True))
    written = _fit_yaml(ctx, "depthnet", {"trainer.max_steps": 12})
    callbacks = yaml.safe_load(written.read_text())["trainer"]["callbacks"]
    (progress,) = [c for c in callbacks if c["class_path"].endswith("ProgressFile")]
    module, name = progress["class_path"].rsplit(".", 1)
    callback = getattr(importlib.import_module(module), name)(**progress["init_args"])
    ctx.run_dir("depthnet").mkdir(parents=True)  # the fit's logger makes it
    callback.on_train_batch_end(SimpleNamespace(global_step=3, max_steps=12), None, None, None, 0)
    assert read_step_fraction(ctx.run_dir("depthnet") / "progress.txt") == pytest.approx(0.25)
