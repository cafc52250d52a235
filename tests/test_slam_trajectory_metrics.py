"""Trajectory metrics: association, Umeyama alignment (cross-checked), ATE, RPE, frame motion, plots."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from c3f_slam import geometry as g
from c3f_slam.evaluation.trajectory import (
    ErrorStats,
    apply_sim3,
    associate,
    ate,
    common_frames_ate,
    evaluate_trajectory,
    frame_motion,
    jitter_ratio,
    registered_share,
    rpe,
    umeyama,
)
from c3f_slam.evaluation.trajectory_plot import plot_trajectories
from c3f_slam.geometry import relative_motion


def _trajectory(n: int = 60, seed: int = 0) -> np.ndarray:
    """A wiggly forward-moving camera-to-world trajectory (metres)."""
    rng = np.random.default_rng(seed)
    poses = [np.eye(4)]
    for _ in range(n - 1):
        t = [rng.normal(0, 0.003), rng.normal(0, 0.003), 0.01]
        step = g.make_pose(g.axis_angle_to_matrix(rng.normal(0, 0.03, 3)), t)
        poses.append(poses[-1] @ step)
    return np.array(poses)


def _random_sim3(rng: np.random.Generator) -> tuple[float, np.ndarray, np.ndarray]:
    return float(rng.uniform(0.2, 5.0)), Rotation.random(random_state=rng).as_matrix(), rng.normal(0, 1.0, 3)


# ---------------------------------------------------------------------- association


def test_associate_exact_and_nearest():
    ie, ig = associate([0.0, 1.0, 2.0], [0.0, 1.0, 2.0])
    assert ie.tolist() == [0, 1, 2] and ig.tolist() == [0, 1, 2]
    # nearest within 20 ms; 2.5 has no partner; 3.003 would also be nearest to 3.001 but that
    # one is taken by the closer 3.0, so it pairs with 3.02 (one-to-one, greedy by |dt|)
    ie, ig = associate([1.0, 2.5, 3.0, 3.003], [0.995, 3.001, 3.02, 10.0], max_dt=0.02)
    pairs = dict(zip(ie.tolist(), ig.tolist()))
    assert pairs == {0: 0, 2: 1, 3: 2}
    ie, _ = associate([3.003], [3.03], max_dt=0.02)
    assert ie.size == 0
    assert associate([], [1.0])[0].size == 0


# ---------------------------------------------------------------------- alignment


def test_umeyama_recovers_known_sim3():
    rng = np.random.default_rng(1)
    src = rng.normal(size=(50, 3))
    s, R, t = _random_sim3(rng)
    dst = s * src @ R.T + t
    s2, R2, t2 = umeyama(src, dst)
    assert s2 == pytest.approx(s, rel=1e-10)
    np.testing.assert_allclose(R2, R, atol=1e-10)
    np.testing.assert_allclose(t2, t, atol=1e-9)
    assert g.is_rotation(R2)


def test_umeyama_agrees_with_scipy_align_vectors():
    """Independent formulation: scipy's Kabsch (align_vectors on centred points) gives the same
    rotation, and the closed-form scale sum<d, R s> / sum|s|^2 the same scale."""
    rng = np.random.default_rng(2)
    src = rng.normal(size=(40, 3))
    s, R, t = _random_sim3(rng)
    dst = s * src @ R.T + t + rng.normal(0, 0.05, size=(40, 3))
    s1, R1, t1 = umeyama(src, dst)
    xs, xd = src - src.mean(0), dst - dst.mean(0)
    rot, _ = Rotation.align_vectors(xd, xs)
    R_ref = rot.as_matrix()
    s_ref = np.sum(xd * (xs @ R_ref.T)) / np.sum(xs**2)
    np.testing.assert_allclose(R1, R_ref, atol=1e-8)
    assert s1 == pytest.approx(s_ref, rel=1e-8)
    np.testing.assert_allclose(t1, dst.mean(0) - s_ref * R_ref @ src.mean(0), atol=1e-8)
    _, R_rigid, _ = umeyama(src, dst, with_scale=False)
    np.testing.assert_allclose(R_rigid, R_ref, atol=1e-8)  # rotation does not depend on scale


def test_umeyama_handles_reflection_case_and_bad_input():
    rng = np.random.default_rng(3)
    src = rng.normal(size=(20, 3))
    _, R, _ = umeyama(src, src * [1, 1, -1])  # mirror: best proper rotation, never a reflection
    assert g.is_rotation(R)
    with pytest.raises(ValueError):
        umeyama(src[:2], src[:2])
    with pytest.raises(ValueError):
        umeyama(np.zeros((5, 3)), src[:5])


# ---------------------------------------------------------------------- ATE / RPE


def test_ate_recovers_scale_and_noise():
    """est = Sim(3)^-1 (gt) + noise: the Sim(3) ATE finds the scale and reports the noise RMSE."""
    rng = np.random.default_rng(4)
    gt = _trajectory(200)
    s, R, t = _random_sim3(rng)
    noise = rng.normal(0, 0.002, size=(len(gt), 3))
    est = apply_sim3(1 / s, R.T, -R.T @ t / s, gt)  # inverse similarity of the ground truth
    est[:, :3, 3] += noise / s
    res = ate(est, gt, "sim3")
    assert res.scale == pytest.approx(s, rel=0.01)
    np.testing.assert_allclose(res.R, R, atol=0.01)
    true_rmse = np.sqrt(np.mean(np.sum(noise**2, axis=1)))
    assert res.stats.rmse == pytest.approx(true_rmse, rel=0.05)
    assert res.stats.rmse <= true_rmse  # the fit can only do better than the true transform
    assert res.stats.max >= res.stats.median and res.stats.n == len(gt)
    # without scale the same estimate is far off; on a rigidly moved copy SE(3) is exact
    assert ate(est, gt, "se3").stats.rmse > 10 * res.stats.rmse or abs(s - 1) < 0.1
    rigid = apply_sim3(1.0, R, t, gt)
    assert ate(rigid, gt, "se3").stats.rmse < 1e-9
    assert ate(gt, gt, "none").stats.max == 0.0
    with pytest.raises(ValueError):
        ate(est, gt, "affine")


def test_rpe_known_perturbation():
    gt = _trajectory(30)
    assert rpe(gt, gt).trans.max < 1e-12
    # every step of the estimate is 1 mm longer sideways and turned by 0.5 degrees
    delta = g.make_pose(g.axis_angle_to_matrix([0.0, np.radians(0.5), 0.0]), [0.001, 0.0, 0.0])
    est = [gt[0]]
    for k in range(1, len(gt)):
        est.append(est[-1] @ g.relative_pose(gt[k - 1], gt[k]) @ delta)
    r = rpe(np.array(est), gt, delta=1)
    assert r.trans.mean == pytest.approx(0.001, rel=1e-6)
    assert r.rot_deg.mean == pytest.approx(0.5, rel=1e-6)
    assert r.trans.n == len(gt) - 1
    assert rpe(gt, gt, delta=100).trans.n == 0


def test_error_stats_and_registered_share():
    st = ErrorStats.of(np.array([3.0, 4.0]))
    assert st.rmse == pytest.approx(np.sqrt(12.5)) and st.median == 3.5 and st.std == 0.5 and st.max == 4.0
    assert np.isnan(ErrorStats.of(np.zeros(0)).rmse)
    assert registered_share(45, 60) == 0.75 and registered_share(3, 0) == 0.0


def test_evaluate_trajectory_and_plot(tmp_path):
    gt = _trajectory(40)
    stamps = np.arange(40) * 0.1
    keep = np.arange(0, 40, 2)  # half of the frames registered
    est = apply_sim3(0.5, np.eye(3), np.zeros(3), gt[keep])
    out = evaluate_trajectory(stamps[keep] + 0.001, est, stamps, gt, n_frames=40)
    json.dumps(out)  # JSON-ready
    assert out["n_associated"] == 20 and out["registered_share"] == 0.5
    assert out["ate_sim3"]["rmse_m"] < 1e-9 and out["ate_sim3"]["scale"] == pytest.approx(2.0)
    assert out["ate_se3"]["rmse_m"] > 0.01
    assert out["rpe"]["trans_max_m"] < 1e-9
    bad = evaluate_trajectory(stamps[:2], gt[:2], stamps, gt)
    assert "error" in bad

    png = tmp_path / "traj.png"
    plot_trajectories(png, gt[:, :3, 3], est[:, :3, 3] * 2, title="test")
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["traj.png"]


def test_a_trajectory_that_never_moves_gets_an_error_not_an_exception():
    """A component whose frames all sit at one pose (e.g. a revisit of one place in a long
    stream) has no Sim(3) alignment: its evaluation says so instead of aborting the run's."""
    gt = _trajectory(20)
    stamps = np.arange(20) * 0.1
    still = np.repeat(gt[:1], 20, axis=0)
    out = evaluate_trajectory(stamps, still, stamps, gt)
    assert out["error"].startswith("ATE undefined") and "ate_sim3" not in out
    assert out["n_associated"] == 20


def test_common_frames_ate_compares_runs_on_shared_frames():
    gt = _trajectory(40)
    stamps = np.arange(40) * 0.1
    rng = np.random.default_rng(3)
    noisy = gt.copy()
    noisy[:, :3, 3] += rng.normal(0, 0.002, (40, 3))
    tracks = {"short": (stamps[:20], gt[:20]), "long": (stamps[5:], noisy[5:])}
    rmse, n = common_frames_ate(tracks, stamps, gt)
    assert n == 15  # frames 5..19
    assert rmse["short"] < 1e-9 and rmse["long"] > 1e-4
    on_common_frames = evaluate_trajectory(stamps[5:20], noisy[5:20], stamps, gt)
    assert rmse["long"] == pytest.approx(on_common_frames["ate_sim3"]["rmse_m"])
    rmse, n = common_frames_ate({"a": (stamps[:2], gt[:2]), "b": (stamps, gt)}, stamps, gt)
    assert n == 2 and rmse == {"a": None, "b": None}


def test_frame_motion_of_a_constant_step():
    # each step moves 2 mm along the camera's x axis and turns 1.5 degrees about its y axis
    step = g.make_pose(g.axis_angle_to_matrix([0.0, np.radians(1.5), 0.0]), [0.002, 0.0, 0.0])
    poses = [np.eye(4)]
    for _ in range(20):
        poses.append(poses[-1] @ step)
    m = frame_motion(np.array(poses))
    assert m.trans.median == pytest.approx(0.002, rel=1e-9)
    assert m.rot_deg.median == pytest.approx(1.5, rel=1e-9)
    assert m.trans.n == 20
    assert frame_motion(np.array(poses), delta=2).rot_deg.max == pytest.approx(3.0, rel=1e-9)
    # per pair: one faster step shows up at its own index
    poses[11] = poses[10] @ g.make_pose(np.eye(3), [0.0, 0.0, 0.005])
    trans, rot = relative_motion(np.array(poses[:12]))
    assert trans.shape == rot.shape == (11,)
    np.testing.assert_allclose(trans[:10], 0.002, rtol=1e-9)
    assert trans[10] == pytest.approx(0.005, rel=1e-9) and rot[10] == pytest.approx(0.0, abs=1e-9)
    assert relative_motion(np.array(poses[:1]))[0].shape == (0,)


def test_jitter_ratio_is_one_for_a_smooth_path_and_grows_with_shaking():
    t = np.arange(300) / 30.0  # 10 s at 30 frames/s
    smooth = np.stack([0.01 * t, 0.005 * np.sin(0.3 * t), np.zeros_like(t)], axis=1)  # 1 cm/s, gently curving
    assert jitter_ratio(smooth, t) == pytest.approx(1.0, abs=0.01)
    rng = np.random.default_rng(0)
    shaken = smooth + rng.normal(0.0, 0.0003, smooth.shape)  # 0.3 mm per frame about a 0.33 mm step
    more = smooth + rng.normal(0.0, 0.001, smooth.shape)
    assert 1.3 < jitter_ratio(shaken, t) < jitter_ratio(more, t)
    assert jitter_ratio(smooth, t * 2) == pytest.approx(jitter_ratio(smooth, t), abs=0.01)  # its own time scale
    gaps = smooth.copy()
    gaps[::7] = np.nan  # unregistered frames are left out
    assert jitter_ratio(gaps, t) == pytest.approx(1.0, abs=0.01)
    assert np.isnan(jitter_ratio(np.zeros((10, 3)), np.arange(10.0)))  # a path that never moves
    assert np.isnan(jitter_ratio(smooth[:2], t[:2]))
