"""Checks without ground truth (c3f_slam.pipeline.self_checks): each must move with the error it
stands for, on runs whose error is known."""

from __future__ import annotations

import shutil
from pathlib import Path

import cv2
import numpy as np
import open3d as o3d
import pytest

from c3f_slam.config import preset as slam_preset
from c3f_slam.geometry import axis_angle_to_matrix, make_pose
from c3f_slam.io import Sequence, read_tum
from c3f_slam.io.sequence import encode_depth, read_depth_png
from c3f_slam.pipeline import run_slam
from c3f_slam.pipeline.self_checks import photometric_agreement
from c3f_slam.view.raycast import MeshScene
from datamodules.synthetic.fixture import make_tiny_sequence

CFG = dict(fragments={"min_correspondences": 15}, coverage={"enabled": False})


@pytest.fixture(scope="module")
def seq(tmp_path_factory) -> Path:
    return make_tiny_sequence(tmp_path_factory.mktemp("checks") / "seq", frames=30, size=128, seed=5)


def _scaled_depth(seq: Path, out: Path, factor: float) -> Path:
    """A copy of ``seq`` whose every other depth file is ``factor`` times the truth (a depth
    network whose scale wobbles)."""
    shutil.copytree(seq, out)
    s = Sequence(out)
    for k, path in enumerate(s.depth_paths):
        if k % 2:
            d = read_depth_png(path, s.camera.depth_scale)
            cv2.imwrite(str(path), encode_depth(d * np.float32(factor), s.camera.depth_scale))
    return out


def test_checks_of_a_good_run_and_of_one_whose_depth_wobbles(seq, tmp_path):
    cfg = slam_preset("colon", **CFG)
    good = run_slam(seq, tmp_path / "good", cfg, progress=False)["checks"]
    assert good["status"] == "ok" and good["frames"] >= 10 and good["keyframe_pairs"] >= 1
    assert good["photometric_zncc"] > 0.5 and good["map_coverage"] > 0.5
    assert good["map_depth_rel"] < 0.05 and good["keyframe_depth_rel"] < 0.05
    assert good["jitter_ratio"] is None  # 30 frames at 30 frames/s: no whole second inside the recording
    bad = run_slam(_scaled_depth(seq, tmp_path / "wobble", 1.1), tmp_path / "bad", cfg, progress=False)["checks"]
    # half the frames 10 % too deep: fewer in the main map, and those disagree with it and each other
    assert bad["map_depth_rel"] > 2 * good["map_depth_rel"]
    assert bad["keyframe_depth_rel"] > 2 * good["keyframe_depth_rel"]


def test_checks_can_be_switched_off_but_the_jitter_ratio_stays(seq, tmp_path):
    cfg = slam_preset("colon", **CFG).with_(checks={"enabled": False}, frames={"max_frames": 12})
    out = run_slam(seq, tmp_path / "off", cfg, progress=False)["checks"]
    assert out["status"] == "off" and "jitter_ratio" in out and "photometric_zncc" not in out


def test_photometric_agreement_falls_as_the_pose_error_grows(seq, tmp_path):
    """At 128 px the comparison is coarse (measured: 0.67 at the run's poses, 0.60 / 0.39 turned
    by 3 / 6 degrees, 0.55 / 0.33 moved by 3 / 6 mm)."""
    run_slam(seq, tmp_path / "run", slam_preset("colon", **CFG), progress=False)
    scene = MeshScene.of(o3d.io.read_triangle_mesh(str(tmp_path / "run" / "mesh.ply")))
    s = Sequence(seq)
    _, poses = read_tum(tmp_path / "run" / "trajectory.txt")
    mask = np.ones((s.camera.height, s.camera.width), bool)

    def agreement(turn_deg: float, move_m: float) -> float:
        error = make_pose(axis_angle_to_matrix(np.radians([0.0, turn_deg, 0.0])), [move_m, 0.0, 0.0])
        return float(np.mean([photometric_agreement(scene, s.camera, poses[i] @ error, s.read_rgb(i), mask)[0]
                              for i in (5, 10, 15, 20, 25)]))

    right = agreement(0.0, 0.0)
    assert right > 0.5
    assert right > agreement(3.0, 0.0) > agreement(6.0, 0.0) + 0.1
    assert right > agreement(0.0, 0.003) > agreement(0.0, 0.006) + 0.1
