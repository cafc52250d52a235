"""The reprojection refit of a pairwise transform (c3f_slam.matching.reprojection) and the
setting that switches it on for predicted depth."""

from __future__ import annotations

import json

import numpy as np
import pytest

from c3f_core.errors import InputError
from c3f_slam import geometry as g
from c3f_slam.config import SlamConfig
from c3f_slam.matching import MatchFilterConfig, kabsch
from c3f_slam.matching.reprojection import refine_by_reprojection

K = np.array([[60.0, 0, 64], [0, 60.0, 64], [0, 0, 1]])  # 128 px, about 93 deg
HUBER = MatchFilterConfig().reprojection_huber_px  # pixels


def _pair(rng, n: int = 40):
    """Frame j's points on a tube-like depth range and a small camera motion T_ij (p_i = T_ij p_j)."""
    T = np.eye(4)
    T[:3, :3] = g.axis_angle_to_matrix(rng.normal(size=3) * 0.02)
    T[:3, 3] = rng.normal(size=3) * 1e-3 + [0, 0, -1e-3]
    uv = rng.uniform(10, 118, (n, 2))
    z = rng.uniform(0.01, 0.06, n)
    p_j = np.c_[(uv - K[:2, 2]) / K[0, 0] * z[:, None], z]
    return T, p_j, g.transform_points(T, p_j)


def _on_rays(p: np.ndarray, rng, depth_share: float, px: float) -> np.ndarray:
    """Points seen by a camera at the origin: each depth off by ``depth_share`` (relative, along
    its ray) and its pixel by ``px``."""
    uv = (K @ p.T).T
    uv = uv[:, :2] / uv[:, 2:] + rng.normal(0, px, (len(p), 2))
    z = p[:, 2] * (1 + rng.normal(0, depth_share, len(p)))
    return np.c_[(uv - K[:2, 2]) / K[0, 0] * z[:, None], z]


def _errors(T: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    E = np.linalg.inv(truth) @ T
    angle = np.degrees(np.arccos(np.clip((np.trace(E[:3, :3]) - 1) / 2, -1, 1)))
    return float(np.linalg.norm(T[:3, 3] - truth[:3, 3])), float(angle)


def test_refit_recovers_an_exact_transform_from_a_wrong_start():
    rng = np.random.default_rng(0)
    T, p_j, p_i = _pair(rng)
    start = T.copy()
    start[:3, :3] = g.axis_angle_to_matrix(np.array([0.01, -0.02, 0.015])) @ T[:3, :3]
    start[:3, 3] += [5e-4, -3e-4, 4e-4]
    np.testing.assert_allclose(refine_by_reprojection(start, p_i, p_j, K, HUBER), T, atol=1e-7)


def test_refit_beats_the_3d_fit_when_the_depth_is_the_noisy_part():
    """Depth off by 5 % (a predicted depth map's order), pixels by 0.3 px: the refit's
    translation and rotation errors are well below Kabsch's (mean over trials)."""
    rng = np.random.default_rng(1)
    err = {"kabsch": [], "refit": []}
    for _ in range(30):
        T, p_j, p_i = _pair(rng)
        q_i, q_j = _on_rays(p_i, rng, 0.05, 0.3), _on_rays(p_j, rng, 0.05, 0.3)
        T0 = kabsch(q_j, q_i)
        err["kabsch"].append(_errors(T0, T))
        err["refit"].append(_errors(refine_by_reprojection(T0, q_i, q_j, K, HUBER), T))
    mean = {k: np.mean(v, axis=0) for k, v in err.items()}
    assert mean["refit"][0] < 0.7 * mean["kabsch"][0], mean  # 0.08x with this seed
    assert mean["refit"][1] < 0.5 * mean["kabsch"][1], mean  # 0.15x


def test_refit_keeps_the_start_when_it_cannot_improve():
    rng = np.random.default_rng(2)
    T, p_j, p_i = _pair(rng, n=2)
    start = np.eye(4)
    assert np.array_equal(refine_by_reprojection(start, p_i, p_j, K, HUBER), start)  # fewer than 3 points
    T, p_j, p_i = _pair(rng)
    assert np.array_equal(refine_by_reprojection(T, p_i, p_j, K, HUBER), T)  # already exact: no lower cost
    bad = p_j.copy()
    bad[:, 2] = np.nan  # no depth anywhere
    assert np.array_equal(refine_by_reprojection(start, p_i, bad, K, HUBER), start)


def test_reprojection_refit_setting():
    """Off by default whatever the depth source; switched on it stays on; a bad threshold is refused."""
    cfg = SlamConfig()
    assert cfg.match_filter.reprojection_refit is False
    assert cfg.for_depth_source("model").match_filter.reprojection_refit is False
    on = cfg.with_(match_filter={"reprojection_refit": True})
    assert on.for_depth_source("model").match_filter.reprojection_refit is True
    with pytest.raises(InputError, match="reprojection_huber_px"):
        MatchFilterConfig(reprojection_huber_px=0)


@pytest.fixture(scope="module")
def seq(tmp_path_factory):
    from datamodules.synthetic.fixture import make_tiny_sequence

    return make_tiny_sequence(tmp_path_factory.mktemp("refit") / "seq", frames=16, size=96, seed=1)


@pytest.mark.parametrize("baseline", ["none", "odometry"])
def test_a_run_with_the_refit_moves_its_poses_a_little(seq, tmp_path, baseline):
    """Wired into both back-ends: with the refit on, the trajectory of the same frames changes
    (so the refit ran) and stays close to the 3D fit's on exact depth; the setting is recorded."""
    from c3f_slam.cli.main import main

    trajectories = {}
    for refit in (False, True):
        out = tmp_path / f"{baseline}_{refit}"
        args = ["run", str(seq), "--depth-source", "files", "--descriptors", "sift", "--out", str(out),
                "--set", "fragments.min_correspondences=15", "--set", "fusion.enabled=false", "--quiet",
                "--set", f"match_filter.reprojection_refit={str(refit).lower()}"]
        if baseline != "none":
            args += ["--set", f"mode={baseline}"]
        assert main(args) == 0
        s = json.loads((out / "summary.json").read_text())
        assert s["config"]["match_filter"]["reprojection_refit"] is refit
        trajectories[refit] = np.loadtxt(out / "trajectory.txt")
    off, on = trajectories[False], trajectories[True]
    assert off.shape == on.shape and len(on) >= 4
    assert not np.array_equal(off, on)
    assert np.abs(on[:, 1:4] - off[:, 1:4]).max() < 2e-3  # metres
