"""`python -m c3f_slam run|evaluate`: outputs, clear one-line errors (exit 2), partial outputs."""

from __future__ import annotations

import json
import math
import shutil
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from c3f_slam.cli.main import main
from c3f_slam.cli.settings_options import REMOVED
from datamodules.synthetic.fixture import make_tiny_sequence
from tests.startup import packages_loaded_by

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def seq(tmp_path_factory) -> Path:
    return make_tiny_sequence(tmp_path_factory.mktemp("cli") / "seq", frames=16, size=96, seed=1)


def _error_line(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: "), err
    return err[0]


def test_help_lists_commands_and_options():
    out = subprocess.run([sys.executable, "-m", "c3f_slam", "run", "--help"], cwd=ROOT, capture_output=True,
                         text=True, timeout=120)
    assert out.returncode == 0
    for opt in ("--depth-source", "--descriptors", "--preset", "--config", "--set", "--print-config",
                "--depth-model", "--feature-model"):
        assert opt in out.stdout
    for usage in REMOVED:  # the former tuning flags: gone from --help (tests/test_slam_removed_flags.py)
        assert usage.split()[0] not in out.stdout, usage


@pytest.mark.e2e
def test_run_and_evaluate(seq, tmp_path, capsys):
    out = tmp_path / "run"
    rc = main(["run", str(seq), "--depth-source", "files", "--descriptors", "sift", "--out", str(out),
               "--set", "fragments.min_correspondences=15", "--quiet"])
    assert rc == 0
    for name in ("trajectory.txt", "summary.json", "keyframe_graph.json", "keyframe_graph.png", "mesh.ply"):
        assert (out / name).is_file(), name
    s = json.loads((out / "summary.json").read_text())
    assert s["status"] == "ok" and s["frames"] == 16
    assert main(["evaluate", str(out), "--gt", str(seq)]) == 0
    printed = capsys.readouterr().out
    assert "ATE sim3" in printed and "cm" in printed and "coverage" in printed
    ev = json.loads((out / "evaluation.json").read_text())
    assert math.isfinite(ev["ate_sim3"]["rmse_m"]) and math.isfinite(ev["ate_se3"]["rmse_m"])
    assert ev["ate_sim3"]["rmse_m"] < 0.05 * ev["gt_length_m"]
    assert 0 < ev["coverage"]["share"] <= 1
    assert (out / "trajectory.png").is_file() and (out / "coverage.ply").is_file()


def test_odometry_baseline_stride_max_frames(seq, tmp_path):
    out = tmp_path / "odo"
    assert main(["run", str(seq), "--out", str(out), "--set", "mode=odometry", "--set", "frames.stride=2",
                 "--set", "frames.max_frames=5", "--set", "fusion.enabled=false", "--quiet"]) == 0
    s = json.loads((out / "summary.json").read_text())
    assert s["mode"] == "odometry" and s["frames"] == 5 and not (out / "mesh.ply").exists()


PAPER_RULES_SETS = ["--set", "candidates.max_candidates=none", "--set", "keyframes.max_loop_edges=none",
                    "--set", "keyframes.reuse=false", "--set", "optimization.growth=none",
                    "--set", "optimization.max_nodes=none", "--set", "optimization.final_nodes=none"]


def test_keyframe_candidates_option(seq, tmp_path, capsys):
    """candidates.max_candidates=N caps global matching; the paper's rules (PAPER_RULES) lift the caps."""
    for name, sets, expect in (("paper", PAPER_RULES_SETS, None), ("6", ["--set", "candidates.max_candidates=6"], 6)):
        out = tmp_path / f"kc{name}"
        assert main(["run", str(seq), "--out", str(out), *sets, "--set", "frames.max_frames=6",
                     "--set", "fragments.min_correspondences=15", "--set", "fusion.enabled=false", "--quiet"]) == 0
        cfg = json.loads((out / "summary.json").read_text())["config"]
        assert cfg["candidates"]["max_candidates"] == expect
        assert (cfg["optimization"]["growth"] is None) == (expect is None)
    bad = tmp_path / "bad"
    assert main(["run", str(seq), "--out", str(bad), "--set", "candidates.max_candidates=-1", "--quiet"]) == 2
    assert "candidates.max_candidates" in _error_line(capsys) and not bad.exists()


@pytest.mark.parametrize(
    "path, cases, bad",
    [
        # blas_threads=N caps NumPy's BLAS threads during the run (default 1; none = the library's)
        ("blas_threads", [(None, 1), ("2", 2), ("none", None)], "-1"),
        # frontend.ratio=R: the matcher's ratio test (default 0.9; none = off; outside [0, 1] is an error)
        ("frontend.ratio", [(None, 0.9), ("0.8", 0.8), ("none", None)], "1.5"),
    ],
)
def test_setting_reaches_config(seq, tmp_path, capsys, path, cases, bad):
    for value, expect in cases:
        args = [] if value is None else ["--set", f"{path}={value}"]
        out = tmp_path / f"o{value}"
        assert main(["run", str(seq), "--out", str(out), "--set", "frames.max_frames=3",
                     "--set", "fusion.enabled=false", "--quiet", *args]) == 0
        value = json.loads((out / "summary.json").read_text())["config"]
        for part in path.split("."):
            value = value[part]
        assert value == expect
    assert main(["run", str(seq), "--out", str(tmp_path / "bad"), "--set", f"{path}={bad}", "--quiet"]) == 2
    assert not (tmp_path / "bad").exists()  # a bad setting stops the command before the run folder
    assert path in _error_line(capsys)


def test_missing_sequence(tmp_path, capsys):
    out = tmp_path / "o"
    assert main(["run", str(tmp_path / "nope"), "--out", str(out), "--quiet"]) == 2
    assert "nope" in _error_line(capsys)
    s = json.loads((out / "summary.json").read_text())
    assert s["status"] == "error" and "nope" in s["error"]


def test_intrinsics_not_matching_frames(seq, tmp_path, capsys):
    bad = tmp_path / "bad"
    shutil.copytree(seq, bad)
    cam = json.loads((bad / "camera.json").read_text())
    cam["width"] = cam["width"] + 8
    (bad / "camera.json").write_text(json.dumps(cam))
    out = tmp_path / "o"
    assert main(["run", str(bad), "--out", str(out), "--quiet"]) == 2
    line = _error_line(capsys)
    assert "bad" in line
    assert json.loads((out / "summary.json").read_text())["status"] == "error"


def test_all_black_sequence_never_registers(seq, tmp_path, capsys):
    bad = tmp_path / "black"
    shutil.copytree(seq, bad)
    for p in sorted((bad / "rgb").glob("*.png"))[:6]:
        cv2.imwrite(str(p), np.zeros((96, 96, 3), np.uint8))
    out = tmp_path / "o"
    assert main(["run", str(bad), "--out", str(out), "--set", "frames.max_frames=6", "--quiet"]) == 2
    assert "no frame could be registered" in _error_line(capsys)
    s = json.loads((out / "summary.json").read_text())
    assert s["status"] == "error" and s["skipped_black"] == 6 and (out / "trajectory.txt").is_file()


def test_onnx_options_fail_clearly(seq, tmp_path, capsys):
    cases = [(["--descriptors", "contrafeat"], "--descriptors contrafeat needs --feature-model"),
             (["--depth-source", "model"], "--depth-source model needs --depth-model"),
             (["--depth-model", str(tmp_path / "d.onnx")], "--depth-model: "),
             (["--feature-model", str(tmp_path / "f.onnx")], "--feature-model: ")]
    for extra, expected in cases:
        assert main(["run", str(seq), "--out", str(tmp_path / "o"), "--quiet", *extra]) == 2
        line = _error_line(capsys)
        assert expected in line, line
        if "-model: " in expected:
            assert ".onnx: model file not found" in line, line


def test_evaluate_without_run(seq, tmp_path, capsys):
    assert main(["evaluate", str(tmp_path), "--gt", str(seq)]) == 2
    assert "trajectory" in _error_line(capsys)


@pytest.mark.parametrize("argv", [["--help"], ["run", "--help"], ["run", "--preset", "room", "--print-config"]],
                         ids=" ".join)
def test_help_and_print_config_import_no_heavy_library(argv):
    """Help and ``--print-config`` read no frames and run no model: they start without NumPy,
    OpenCV, Open3D or onnxruntime (a run imports them when it starts)."""
    loaded = packages_loaded_by("c3f_slam", *argv)
    assert "c3f_slam" in loaded
    assert not loaded & {"numpy", "cv2", "open3d", "onnxruntime", "scipy", "torch"}, sorted(loaded)
