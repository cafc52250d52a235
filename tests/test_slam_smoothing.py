"""Smooth trajectories on predicted depth (docs/design.md): the constant-velocity motion prior
on the final path, a reusing fragment placed between its host's match and its odometry, and
frames linked across skipped ones; each on a case where the answer is known."""

from __future__ import annotations

import numpy as np
import pytest

from c3f_core.errors import InputError
from c3f_slam.config import SlamConfig
from c3f_slam.config.smoothing import PREDICTED_DEPTH_MOTION_PRIOR_S, SmoothingConfig
from c3f_slam.evaluation.trajectory import jitter_ratio
from c3f_slam.geometry import axis_angle_to_matrix, invert_pose, make_pose
from c3f_slam.pipeline.fragment_map import FragmentMap, blend_poses
from c3f_slam.pipeline.frame_step import FrameInput
from c3f_slam.pipeline.frontend import FrameFeatures, PairMatch
from c3f_slam.pipeline.keyframe_edges import KeyframeEdge
from c3f_slam.pipeline.slam import FragmentSlam
from c3f_slam.pipeline.smoothing import path_pieces, smooth_poses
from c3f_slam.posegraph import EdgeKind

K = np.array([[40.0, 0, 31.5], [0, 40.0, 31.5], [0, 0, 1]])


def _path(n: int, fps: float, speed=(0.01, 0.002, 0.0), turn=(0.0, 0.2, 0.05)) -> tuple[np.ndarray, np.ndarray]:
    """(stamps, poses) of a camera at constant velocity (m/s) and constant turn rate (rad/s)."""
    t = np.arange(n) / fps
    poses = np.stack([make_pose(axis_angle_to_matrix(np.multiply(turn, s)), np.multiply(speed, s)) for s in t])
    return t, poses


def _rot_deg(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    M = np.einsum("nji,njk->nik", A[:, :3, :3], B[:, :3, :3])
    return np.degrees(np.arccos(np.clip((np.trace(M, axis1=1, axis2=2) - 1) / 2, -1, 1)))


# ---------------------------------------------------------------------- the motion prior

def test_constant_velocity_passes_unchanged():
    """A path at constant velocity and turn rate is what the prior prefers: nothing moves (the
    orientations' quaternions of a steady turn are not exactly linear in time: 0.0002 deg)."""
    t, P = _path(90, 30.0)
    S = smooth_poses(t, P, 0.1)
    np.testing.assert_allclose(S[:, :3, 3], P[:, :3, 3], atol=1e-9)
    assert _rot_deg(S, P).max() < 1e-3


def test_noise_is_removed_and_the_cutoff_is_in_seconds():
    """White noise of 0.3 mm and 0.5 deg per frame on a constant-velocity path: the prior takes
    most of it out, about as much at 30 and at 60 frames/s (the cut-off is a time), and the
    path's jitter ratio comes back near 1."""
    rng = np.random.default_rng(0)
    errs = {}
    for fps in (30.0, 60.0):
        t, P = _path(int(4 * fps), fps)
        noisy = P.copy()
        noisy[:, :3, 3] += rng.normal(0, 3e-4, (len(P), 3))
        for i in range(len(P)):
            noisy[i, :3, :3] = noisy[i, :3, :3] @ axis_angle_to_matrix(rng.normal(0, np.radians(0.5), 3))
        S = smooth_poses(t, noisy, 0.1)
        raw = np.sqrt(np.mean(np.sum((noisy - P)[:, :3, 3] ** 2, axis=1)))
        smooth = np.sqrt(np.mean(np.sum((S - P)[:, :3, 3] ** 2, axis=1)))
        assert smooth < 0.5 * raw
        assert np.mean(_rot_deg(S, P)) < 0.5 * np.mean(_rot_deg(noisy, P))
        assert jitter_ratio(noisy[:, :3, 3], t) > 1.5 and jitter_ratio(S[:, :3, 3], t) < 1.1
        errs[fps] = smooth / raw
    assert errs[60.0] < errs[30.0]  # more frames per second of the same noise: more of it averaged out


def test_velocity_changes_slower_than_the_cutoff_pass():
    """A sideways sway at 0.2 Hz (well below 1 / (2 pi 0.1 s) = 1.6 Hz) keeps over 99 % of
    its amplitude; at 5 Hz most of it is taken out."""
    for hz, kept in ((0.2, (0.99, 1.01)), (5.0, (0.0, 0.1))):
        t = np.arange(300) / 30.0
        P = np.tile(np.eye(4), (len(t), 1, 1))
        P[:, 0, 3] = 0.002 * np.sin(2 * np.pi * hz * t)
        P[:, 2, 3] = 0.01 * t
        S = smooth_poses(t, P, 0.1)
        inner = slice(60, 240)  # away from the ends
        gain = np.std(S[inner, 0, 3]) / np.std(P[inner, 0, 3])
        assert kept[0] <= gain <= kept[1], (hz, gain)


def test_a_true_turn_keeps_its_sharpness_with_the_robust_weights():
    """The camera goes 2 cm/s along x for 1.5 s, then back (a sharp turn), with 0.05 mm of
    noise: the plain prior rounds the turn off (0.5 mm off around it); with the Huber weights
    the turn stands out from the path's usual accelerations and stays sharp, and the noise
    elsewhere is still taken out."""
    rng = np.random.default_rng(2)
    t = np.arange(90) / 30.0
    true = np.tile(np.eye(4), (len(t), 1, 1))
    true[:, 0, 3] = np.where(t < 1.5, 0.02 * t, 0.03 - 0.02 * (t - 1.5))
    true[:, 2, 3] = 0.005 * t
    noisy = true.copy()
    noisy[:, :3, 3] += rng.normal(0, 5e-5, (len(t), 3))
    turn = np.abs(t - 1.5) < 0.2

    def rms(P, where):
        return np.sqrt(np.mean(np.sum((P - true)[where, :3, 3] ** 2, axis=1)))

    plain, robust = smooth_poses(t, noisy, 0.1, robust_k=0.0), smooth_poses(t, noisy, 0.1, robust_k=3.0)
    assert rms(plain, turn) > 3e-4 and rms(robust, turn) < 1.5e-4
    assert rms(robust, ~turn) < 0.5 * rms(noisy, ~turn)
    # a path without such events gets the same weights everywhere: the robust prior is the plain one
    t2, P2 = _path(60, 30.0)
    P2[:, :3, 3] += rng.normal(0, 1e-4, (60, 3))
    assert np.abs(smooth_poses(t2, P2, 0.1, robust_k=3.0) - smooth_poses(t2, P2, 0.1)).max() < 5e-5


def test_gaps_split_the_path_and_edge_cases():
    t = np.array([0.0, 0.1, 0.2, 1.5, 1.6, 1.7, 1.8])
    assert [p.tolist() for p in path_pieces(t, 0.5)] == [[0, 1, 2], [3, 4, 5, 6]]
    assert [p.tolist() for p in path_pieces(np.array([0.0, 0.1, 0.1, 0.2]), 0.5)] == [[0, 1], [2, 3]]
    # a jump across a long gap stays a jump: the two pieces do not pull on each other
    P = np.tile(np.eye(4), (len(t), 1, 1))
    P[3:, 0, 3] = 0.05
    P[:, 2, 3] = t * 0.01
    np.testing.assert_allclose(smooth_poses(t, P, 0.2, max_gap_s=0.5), P, atol=1e-12)
    assert np.abs(smooth_poses(t, P, 0.2, max_gap_s=2.0) - P).max() > 1e-3
    np.testing.assert_array_equal(smooth_poses(t, P, 0.0), P)  # off
    np.testing.assert_array_equal(smooth_poses(t[:2], P[:2], 0.1), P[:2])  # too short to smooth
    with pytest.raises(ValueError):
        smooth_poses(t[:3], P, 0.1)


# ---------------------------------------------------------------------- settings

def test_settings_resolve_from_the_depth_source_and_validate():
    s = SmoothingConfig()
    assert s.prior_s == 0.0  # unresolved: off
    model, files = s.for_depth_source("model"), s.for_depth_source("files")
    assert model.motion_prior_s == PREDICTED_DEPTH_MOTION_PRIOR_S > 0 and files.motion_prior_s == 0.0
    assert SmoothingConfig(motion_prior_s=0.3).for_depth_source("files").motion_prior_s == 0.3  # a given value stays
    assert SlamConfig().for_depth_source("model").smoothing.motion_prior_s == PREDICTED_DEPTH_MOTION_PRIOR_S
    assert SlamConfig().for_depth_source("files").smoothing.prior_s == 0.0
    assert SlamConfig().with_(smoothing={"max_gap_s": 1.0}).smoothing.max_gap_s == 1.0
    for bad in ({"motion_prior_s": -0.1}, {"max_gap_s": 0}, {"robust_k": 0.5}, {"robust_iterations": 0}):
        with pytest.raises(InputError, match="smoothing."):
            SmoothingConfig(**bad)
    with pytest.raises(InputError, match="keyframes.reuse_odometry_weight"):
        SlamConfig().with_(keyframes={"reuse_odometry_weight": 1.5})


# ---------------------------------------------------------------------- the back-end

def _scene(n_points: int = 80, seed: int = 0):
    """World points in front of the camera (a patch 2-4 cm away) with a unique descriptor each."""
    rng = np.random.default_rng(seed)
    pts = np.column_stack([rng.uniform(-0.012, 0.012, n_points), rng.uniform(-0.012, 0.012, n_points),
                           rng.uniform(0.02, 0.04, n_points)])
    desc = rng.gamma(0.6, 30.0, (n_points, 128)).clip(0, 255).astype(np.uint8)
    return pts, desc


def _frame(i: int, stamp: float, T_wc: np.ndarray, pts_w: np.ndarray, desc: np.ndarray, noise: float = 0.0,
           rng=None, offset=None) -> FrameInput:
    """The frame a camera at ``T_wc`` sees of the scene (``noise``: metres on every point;
    ``offset``: metres added to every point, a depth error the rigid fit turns into a shift)."""
    p = pts_w @ invert_pose(T_wc)[:3, :3].T + invert_pose(T_wc)[:3, 3]
    if noise:
        p = p + rng.normal(0, noise, p.shape)
    if offset is not None:
        p = p + offset
    xy = (p[:, :2] / p[:, 2:] * K[0, 0] + K[0, 2]).astype(np.float32)
    feat = FrameFeatures(i, stamp, xy, desc, p.astype(np.float32))
    return FrameInput(feat, np.full((64, 64), 0.03, np.float32))


def _slam(smoothing: dict | None = None, **parts) -> FragmentSlam:
    parts = {"fragments": {"min_correspondences": 15}, "fusion": {"enabled": False}, **parts}
    cfg = SlamConfig().with_(smoothing={"motion_prior_s": 0.0, **(smoothing or {})}, **parts)
    return FragmentSlam(cfg.for_depth_source("model"), K)


def _run(slam: FragmentSlam, frames: list[FrameInput | None]) -> np.ndarray:
    """Feed ``frames`` (None: a skipped frame), finish; the trajectory's poses (N, 4, 4)."""
    for i, f in enumerate(frames):
        if f is None:
            slam.skip(i, i / 30.0)
        else:
            slam.add(f)
    slam.finish()
    return slam.map.trajectory()[2]


def test_the_motion_prior_in_the_map_smooths_a_noisy_path():
    """Points with 0.3 mm noise per frame on a camera at constant velocity: the map's final
    path (trajectory, and every pose fusion reads) is closer to the truth with the prior, its
    frame-to-frame steps much closer (what is left is the slow drift the prior cannot see)."""
    pts, desc = _scene(120)
    poses = [make_pose(np.eye(3), [0.0003 * i, 0.0001 * i, 0.0002 * i]) for i in range(40)]
    true_steps = np.diff(np.stack(poses)[:, :3, 3], axis=0)
    err, step_err = {}, {}
    for tau in (0.0, 0.15):
        rng = np.random.default_rng(5)
        frames = [_frame(i, i / 30, T, pts, desc, noise=3e-4, rng=rng) for i, T in enumerate(poses)]
        slam = _slam({"motion_prior_s": tau})
        P = _run(slam, frames)
        assert np.isfinite(P).all()
        err[tau] = np.sqrt(np.mean(np.sum((P[:, :3, 3] - np.stack(poses)[:, :3, 3]) ** 2, axis=1)))
        step_err[tau] = np.sqrt(np.mean(np.sum((np.diff(P[:, :3, 3], axis=0) - true_steps) ** 2, axis=1)))
        rows = np.arange(len(poses))
        np.testing.assert_allclose(np.stack([slam.map.pose_of_log(r) for r in rows]), P)
        np.testing.assert_allclose(slam.map.components()[0].poses, P)
    assert err[0.15] < 0.85 * err[0.0] and step_err[0.15] < 0.5 * step_err[0.0], (err, step_err)


# ---------------------------------------------------------------------- skipped frames

@pytest.mark.parametrize("across", [True, False])
def test_frames_link_across_skipped_frames(across):
    """A skipped frame (a repeat, a black frame) between two frames: by default the next frame
    is matched to the last processed one and the fragment goes on (its frames' rows are not
    contiguous); with ``rejoin.across_skipped`` false the skip breaks the track."""
    pts, desc = _scene()
    poses = [make_pose(np.eye(3), [0.0005 * i, 0, 0]) for i in range(7)]
    frames = [None if i in (2, 3) else _frame(i, i / 30, T, pts, desc) for i, T in enumerate(poses)]
    slam = _slam(rejoin={"across_skipped": across})
    P = _run(slam, frames)
    reg = np.isfinite(P).all(axis=(1, 2))
    assert reg.tolist() == [True, True, False, False, True, True, True]
    np.testing.assert_allclose(P[reg][:, :3, 3], np.stack(poses)[reg][:, :3, 3], atol=1e-6)
    s = slam.stats()
    assert s["fragments"] == (1 if across else 2)
    assert s["tracking_breaks"] == (0 if across else 1)


# ---------------------------------------------------------------------- reuse

def test_blend_poses_goes_part_of_the_way():
    A = make_pose(axis_angle_to_matrix([0.0, 0.1, 0.0]), [0.01, 0.0, 0.0])
    B = A @ make_pose(axis_angle_to_matrix([0.0, 0.0, 0.2]), [0.0, 0.002, 0.0])
    np.testing.assert_allclose(blend_poses(A, B, 0.0), A, atol=1e-12)
    np.testing.assert_allclose(blend_poses(A, B, 1.0), B, atol=1e-12)
    half = blend_poses(A, B, 0.5)
    np.testing.assert_allclose(half, A @ make_pose(axis_angle_to_matrix([0.0, 0.0, 0.1]), [0.0, 0.001, 0.0]),
                               atol=1e-12)


@pytest.mark.parametrize("weight", [0.0, 0.5, 1.0])
def test_a_reusing_fragment_starts_between_its_host_match_and_its_odometry(weight):
    """A fragment hung off host keyframe 0 (a revisit) whose match to the host puts its first
    frame 0.5 mm and 2 deg from where the odometry link from the frame before (hung off keyframe
    1) puts it: ``keyframes.reuse_odometry_weight`` places it that share of the way from the
    first to the second; without an odometry link, the host's match alone."""
    pts, desc = _scene(40)
    slam_map = FragmentMap(SlamConfig().with_(keyframes={"reuse_odometry_weight": weight}))
    slam_map.graph.add_node(np.eye(4))
    slam_map.graph.add_node(make_pose(np.eye(3), [0.002, 0, 0]))
    slam_map.graph.add_edge(0, 1, make_pose(np.eye(3), [0.002, 0, 0]), points_j=pts)
    by_host = make_pose(axis_angle_to_matrix([0, 0.01, 0]), [0.001, 0, 0])  # T_host,new
    odo = make_pose(axis_angle_to_matrix([0, np.radians(2) + 0.01, 0]), [-0.0005, 0, 0])  # T_1,new
    by_odometry = slam_map.graph.pose(1) @ odo  # T_host,new by the odometry (host at the origin)
    frame = _frame(9, 0.3, np.eye(4), pts, desc)
    host = KeyframeEdge(0, PairMatch(by_host, pts, 40), EdgeKind.LOOP)
    slam_map.attach(0, frame, "overlap", [host], KeyframeEdge(1, PairMatch(odo, pts, 40), EdgeKind.ODOMETRY))
    np.testing.assert_allclose(slam_map.active.base, blend_poses(by_host, by_odometry, weight), atol=1e-12)
    assert np.linalg.norm(by_odometry[:3, 3] - by_host[:3, 3]) == pytest.approx(0.0005)
    slam_map.attach(1, frame, "overlap", [host])  # no odometry link: the host's match
    np.testing.assert_allclose(slam_map.active.base, by_host, atol=1e-12)
