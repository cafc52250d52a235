"""Bad input to ``python -m c3f_slam`` and ``python -m datamodules convert`` (no torch): exit status
2, one ``error:`` line naming the file or option, the output folder as it was or, where the run
records its failure, a run folder marked so (tests/bad_input.py); Ctrl-C during a run over a
complete earlier run leaves the partial run marked status error, nothing of the earlier one.

The cases of the former ``benchmarks/fault_injection.py`` that no other test covered; the rest
are in test_slam_cli.py (missing sequence, camera.json not matching the frames),
test_slam_run_folder.py (corrupt frames, a complete run without --overwrite) and
test_slam_models.py (a model of the wrong kind)."""

from __future__ import annotations

import json
import shutil
import sys
from dataclasses import dataclass
from pathlib import Path

import cv2
import pytest

from c3f_slam.cli.main import main as slam_main
from c3f_slam.pipeline.keyframe_store import CACHE_DIR as KEYFRAME_CACHE
from c3f_slam.pipeline.keyframe_store import DATA_FILE as KEYFRAME_DATA
from datamodules.__main__ import main as data_main
from datamodules.synthetic.fixture import make_tiny_sequence
from tests import onnx_fixtures
from tests.bad_input import Case, check_refused, error_line, interrupt, left_beside

SIZE = 128  #: frame side (pixels): enough correspondences to register the tiny sequences
RUN = ["--set", "fragments.min_correspondences=15", "--quiet"]
LONG = 240  #: frames of the interrupted run: enough that Ctrl-C comes before its last frame is read


@dataclass(frozen=True)
class Inputs:
    """What the cases start from: a sequence, a complete run on it (with a mesh), a depth model."""

    seq: Path
    run: Path
    depth_model: Path


@pytest.fixture(scope="module")
def inputs(tmp_path_factory) -> Inputs:
    root = tmp_path_factory.mktemp("bad_input")
    seq = make_tiny_sequence(root / "seq", frames=10, size=SIZE, seed=3)
    assert slam_main(["run", str(seq), "--out", str(root / "run"), *RUN]) == 0
    model = onnx_fixtures.depth_model(root / "depth.onnx", (32, 32), (112, 112))
    return Inputs(seq, root / "run", model)


def evaluate_nan_poses(x: Inputs, tmp: Path) -> Case:
    gt, out = tmp / "gt", tmp / "out"
    shutil.copytree(x.seq, gt)
    shutil.copytree(x.run, out)
    lines = (gt / "poses.txt").read_text().splitlines()
    fields = lines[3].split()
    lines[3] = " ".join([fields[0], "nan", *fields[2:]])
    (gt / "poses.txt").write_text("\n".join(lines) + "\n")
    return Case(slam_main, ["evaluate", str(out), "--gt", str(gt)], out, ("poses.txt:4", "non-finite"))


def run_garbage_depth_model(x: Inputs, tmp: Path) -> Case:
    model, out = tmp / "garbage.onnx", tmp / "out"
    model.write_bytes(b"not an onnx model\x00" * 64)
    return Case(slam_main, ["run", str(x.seq), "--depth-model", str(model), "--out", str(out), *RUN], out,
                ("--depth-model", "garbage.onnx", "not a readable ONNX model"), {"status": "error", "frames": 0})


def run_garbage_depth_model_over_complete_run(x: Inputs, tmp: Path) -> Case:
    """Bad input with --overwrite over a complete run: the complete run stays as it was."""
    model, out = tmp / "garbage.onnx", tmp / "out"
    model.write_bytes(b"not an onnx model\x00" * 64)
    shutil.copytree(x.run, out)
    return Case(slam_main, ["run", str(x.seq), "--depth-model", str(model), "--out", str(out), "--overwrite", *RUN],
                out, ("--depth-model", "garbage.onnx", "not a readable ONNX model"))


def run_truncated_video(x: Inputs, tmp: Path) -> Case:
    """A video cut at half its bytes: the frames before the cut are run, and the run says so."""
    video, out = tmp / "clip.avi", tmp / "out"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 10.0, (SIZE, SIZE))
    for frame in sorted((x.seq / "rgb").glob("*.png")):
        writer.write(cv2.imread(str(frame)))
    writer.release()
    data = video.read_bytes()
    video.write_bytes(data[: len(data) // 2])
    shutil.copy(x.seq / "camera.json", tmp / "camera.json")
    return Case(slam_main, ["run", str(video), "--depth-model", str(x.depth_model), "--out", str(out),
                            "--set", "fusion.enabled=false", *RUN],
                out, ("clip.avi", "the video ended after 5 of the 10 frames"),
                {"status": "truncated", "frames": 5})


def convert_missing_folder(x: Inputs, tmp: Path) -> Case:
    out = tmp / "out"
    return Case(data_main, ["convert", "uts", str(tmp / "nowhere"), "--out", str(out), "--no-progress"], out,
                ("nowhere", "folder not found"))


def convert_project_layout_as_c3vd(x: Inputs, tmp: Path) -> Case:
    data, out = tmp / "data", tmp / "out"
    shutil.copytree(x.seq, data / "seq")
    return Case(data_main, ["convert", "c3vd", str(data), "--out", str(out), "--no-progress"], out,
                (str(data), "no C3VD sequences found", "project-layout"))


CASES = {
    "evaluate: NaN in the ground truth's poses.txt": evaluate_nan_poses,
    "run: --depth-model a garbage .onnx": run_garbage_depth_model,
    "run --overwrite: a garbage --depth-model over a complete run": run_garbage_depth_model_over_complete_run,
    "run: video cut at half its bytes, --depth-model": run_truncated_video,
    "convert: missing source folder": convert_missing_folder,
    "convert: c3vd given a folder in the project's layout": convert_project_layout_as_c3vd,
}


@pytest.mark.parametrize("make", CASES.values(), ids=CASES.keys())
def test_bad_input_is_one_line_and_keeps_earlier_outputs(make, inputs, tmp_path, capsys):
    check_refused(make(inputs, tmp_path), capsys)


def _first_keyframe_stored(out: Path) -> bool:
    """The run being built beside ``out`` has processed its first frame (its keyframe is in the
    keyframe cache), so an interrupt now comes after at least one frame, however loaded the machine."""
    return any((out.parent / name / KEYFRAME_CACHE / KEYFRAME_DATA).is_file()
               and (out.parent / name / KEYFRAME_CACHE / KEYFRAME_DATA).stat().st_size > 0
               for name in left_beside(out))


@pytest.mark.e2e
def test_ctrl_c_during_a_run_over_a_complete_run(inputs, tmp_path):
    """SIGINT to ``c3f_slam run --overwrite`` while it works: exit 130, one line saying where the
    partial run is; OUT holds that run marked status error, nothing of the earlier complete run
    (its mesh), and nothing is left beside it."""
    long_seq = make_tiny_sequence(tmp_path / "long", frames=LONG, size=SIZE, seed=5)
    out = tmp_path / "out"
    shutil.copytree(inputs.run, out)
    assert (out / "mesh.ply").is_file()
    cmd = [sys.executable, "-m", "c3f_slam", "run", str(long_seq), "--out", str(out), "--overwrite", *RUN]
    code, err = interrupt(cmd, lambda: _first_keyframe_stored(out), delay_s=0.5)  # the run is built beside OUT
    assert code == 130
    assert error_line(err) == f"error: interrupted; the run so far is in {out} (summary.json status error)"
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "error" and 0 < summary["frames"] < LONG
    assert not (out / "mesh.ply").exists() and left_beside(out) == []
