"""Dense refinement of keyframe edges (c3f_slam.pipeline.refine): coloured ICP from the sparse
estimate, verified; wiring into the config, the CLI and the back-end."""

from __future__ import annotations

import numpy as np
import pytest

from c3f_core.errors import InputError
from c3f_slam import geometry as g
from c3f_slam.camera.intrinsics import PinholeCamera
from c3f_slam.cli.inputs import settings_from_args as _settings
from c3f_slam.cli.main import _parser
from c3f_slam.config import preset as slam_preset
from c3f_slam.pipeline import RunInputs, run_slam
from c3f_slam.pipeline.fallback import RgbdFrame
from c3f_slam.pipeline.frontend import PairMatch
from c3f_slam.pipeline.keyframe_edges import KeyframeEdge
from c3f_slam.pipeline.refine import EdgeRefiner, cloud_pyramid
from c3f_slam.posegraph import EdgeKind
from datamodules.synthetic.room import camera_path, kinect_noise, render, room_scene, room_sequence

CAM = PinholeCamera.from_fov(160, 120, 60.0)


@pytest.fixture(scope="module")
def pair():
    """Two room views 2 frames apart (9 cm, 8 degrees) on the benchmark's path (noisy depth), and T_a,b (truth)."""
    scene, tex = room_scene()
    poses = camera_path(120)
    rng = np.random.default_rng(0)
    views = []
    for T in poses[[10, 12]]:
        rgb, depth = render(scene, tex, CAM, T)
        views.append((rgb, kinect_noise(depth, rng)))
    return views, g.invert_pose(poses[10]) @ poses[12]


def _error(T, T_true):
    step, turn = g.motion_magnitudes((g.invert_pose(T_true) @ T)[None])
    return float(step[0]), float(turn[0])


def _refiner(views, cfg=None):
    r = EdgeRefiner(cfg or slam_preset("room").refine, CAM.K)
    r.observe(*views[0])
    r.keep(0)
    r.observe(*views[1])
    return r


def test_refinement_lowers_the_edge_error(pair):
    views, T_true = pair
    T_sparse = T_true @ g.make_pose(g.axis_angle_to_matrix([0.0, 0.015, 0.01]), [0.03, -0.02, 0.02])
    r = _refiner(views)
    out = r.refine_edges([KeyframeEdge(0, PairMatch(T_sparse, np.zeros((0, 3)), 50), EdgeKind.LOOP)])
    assert list(out) == [0] and r.stats()["refine_accepted"] == 1
    before, after = _error(T_sparse, T_true), _error(out[0].T, T_true)
    assert after[0] < 0.3 * before[0] and after[1] < before[1]
    info = out[0].information
    assert info.shape == (6, 6) and np.allclose(info, info.T) and info[5, 5] > 100  # dense correspondences


def test_a_sparse_edge_that_fits_as_well_is_kept(pair):
    views, T_true = pair
    r = _refiner(views)
    assert r.refine_edges([KeyframeEdge(0, PairMatch(T_true, np.zeros((0, 3)), 50), EdgeKind.LOOP)]) == {}
    assert r.stats()["refine_outcomes"] == {"no_gain": 1}
    r = _refiner(views, slam_preset("room", refine={"min_gain": 0.0}).refine)
    out = r.refine_edges([KeyframeEdge(0, PairMatch(T_true, np.zeros((0, 3)), 50), EdgeKind.LOOP)])
    assert list(out) == [0] and _error(out[0].T, T_true)[0] < 0.01  # within the noise of the depth


def test_wrong_start_is_rejected_and_keeps_the_sparse_edge(pair):
    views, T_true = pair
    T_bad = T_true @ g.make_pose(g.axis_angle_to_matrix([0.0, 0.3, 0.0]), [0.4, 0.0, 0.0])
    r = _refiner(views)
    assert r.refine_edges([KeyframeEdge(0, PairMatch(T_bad, np.zeros((0, 3)), 50), EdgeKind.LOOP)]) == {}
    s = r.stats()
    assert s["refine_attempts"] == 1 and s["refine_accepted"] == 0


def test_textureless_plane_keeps_the_sparse_edge():
    """A flat grey wall fills both views: ICP can slide in the plane without changing the fit,
    so no start (2 or 15 cm off in the plane) is "refined"; the sparse edge stays."""
    cfg = slam_preset("room").refine
    depth = np.full((120, 160), 2.0, np.float32)
    rgb = np.full((120, 160, 3), 128, np.uint8)
    for offset in (0.02, 0.15):
        r = EdgeRefiner(cfg, CAM.K)
        r.observe(rgb, depth)
        r.keep(0)
        r.observe(rgb, depth)
        T_start = g.make_pose(np.eye(3), [offset, 0.0, 0.0])
        assert r.refine_edges([KeyframeEdge(0, PairMatch(T_start, np.zeros((0, 3)), 50), EdgeKind.LOOP)]) == {}
        assert r.stats()["refine_outcomes"] == {"no_gain": 1}


def test_no_depth_or_no_image_means_no_refinement(pair):
    views, _ = pair
    cfg = slam_preset("room").refine
    assert cloud_pyramid(RgbdFrame.from_rgb(views[0][0], np.zeros((120, 160))), CAM.K, cfg) is None
    r = _refiner(views)
    r.observe(None, views[1][1])
    assert r.refine_edges([KeyframeEdge(0, PairMatch(np.eye(4), np.zeros((0, 3)), 9), EdgeKind.LOOP)]) == {}
    r = _refiner(views)  # an edge to a keyframe whose clouds are not kept
    assert r.refine_edges([KeyframeEdge(5, PairMatch(np.eye(4), np.zeros((0, 3)), 9), EdgeKind.LOOP)]) == {}
    assert r.stats()["refine_attempts"] == 0


def test_config_presets_and_validation():
    room, colon = slam_preset("room").refine, slam_preset("colon").refine
    assert room.voxels == (0.08, 0.04, 0.02) and colon.voxels == (0.002, 0.001, 0.0005)
    assert not colon.enabled
    with pytest.raises(InputError, match="refine.voxels"):
        slam_preset("room", refine={"voxels": (0.1, 0.05), "iterations": (10,)})
    with pytest.raises(InputError, match="refine.min_fitness"):
        slam_preset("room", refine={"min_fitness": 2.0})


@pytest.mark.parametrize("flag, expect", [(["--set", "refine.enabled=true"], True),
                                          (["--set", "refine.enabled=false"], False), ([], False),
                                          (["--set", "refine.enabled=true", "--set", "refine.enabled=false"], False)])
def test_cli_flag(flag, expect):
    """--set refine.enabled reaches the setting; the last one given wins."""
    args = _parser().parse_args(["run", "SEQ", "--out", "OUT", *flag])
    assert _settings(args)[0].refine.enabled is expect


@pytest.mark.e2e
def test_run_with_refinement_counts_and_registers(tmp_path):
    seq = room_sequence(tmp_path / "room", frames=24, width=160, height=120)
    s = {}
    for on in (False, True):
        cfg = slam_preset("room", refine={"enabled": on}, fusion={"enabled": False})
        s[on] = run_slam(seq, tmp_path / f"out_{on}", cfg, RunInputs(descriptors="sift", depth_source="files"),
                         progress=False)
    assert s[False]["refine_attempts"] == 0
    assert s[True]["refine_attempts"] >= 1 and 0 <= s[True]["refine_accepted"] <= s[True]["refine_attempts"]
    assert s[True]["registered_frames"] >= s[False]["registered_frames"] > 0
