"""Unseen-surface estimate (issue 20) on analytic tubes: a straight tube seen all round, the
same tube with a band of angles no camera looks at, a fold that hides the wall behind it."""

from __future__ import annotations

import numpy as np
import pytest

from c3f_slam.camera import PinholeCamera
from c3f_slam.coverage import CoverageConfig, ViewSettings, centreline_from_path, compute_coverage
from c3f_slam.geometry import transport_frames
from tests.scenes import tube_mesh, tube_views

CAM = PinholeCamera.from_fov(32, 32, 60.0)
VIEW = ViewSettings(CAM.width, CAM.height, 0.001, 0.2)
CFG = CoverageConfig()
S0, SIGMA = 0.05, 0.0025  # the fold: 5 cm along the tube, Gaussian width 2.5 mm


def _rows(cov, lo: float, hi: float) -> np.ndarray:
    s = cov.wall.s_centres
    return (s >= lo) & (s < hi)


def test_transport_frames_stay_orthonormal_without_twist():
    t = np.tile([0.0, 0.0, 1.0], (5, 1))
    n, b = transport_frames(t)
    assert np.allclose(n, [1.0, 0.0, 0.0]) and np.allclose(b, [0.0, 1.0, 0.0])
    a = np.linspace(0, np.pi / 2, 50)
    t = np.stack([np.cos(a), np.sin(a), np.zeros_like(a)], axis=1)  # a planar quarter circle
    n, b = transport_frames(t)
    assert np.allclose(np.einsum("ij,ij->i", b, t), 0, atol=1e-12)
    assert np.allclose(n, [0.0, 0.0, 1.0], atol=1e-9)  # the normal off the plane stays: no twist


def test_centreline_follows_forward_travel_only():
    """Back-and-forth and sideways motion add no length: 0 .. the farthest position."""
    z = np.concatenate([np.linspace(0, 0.08, 40), np.linspace(0.08, 0.03, 20), np.linspace(0.03, 0.1, 30)])
    wobble = 0.004 * np.sin(np.arange(len(z)))
    line = centreline_from_path(np.stack([wobble, 0 * z, z], axis=1), 0.005, 0.01, 0.002)
    assert line.length == pytest.approx(0.1, abs=0.004)
    assert np.all(np.diff(line.points[:, 2]) > 0)  # monotone along the tube
    assert centreline_from_path(np.zeros((10, 3)), 0.005, 0.01, 0.002) is None


def test_straight_tube_seen_all_round_is_fully_observed():
    poses = tube_views(np.arange(0, 0.1001, 0.004), np.arange(0, 360, 20))
    cov = compute_coverage(tube_mesh(), poses, CAM.K, VIEW, CFG)
    assert cov.length == pytest.approx(0.1, abs=0.002)
    assert cov.unseen_share() < 0.01
    assert cov.area.sum() == pytest.approx(2 * np.pi * 0.025 * cov.length, rel=0.01)
    assert all(seg["unseen_share"] < 0.01 for seg in cov.segments(0.05))


def test_band_never_in_view_is_its_share():
    """Views at 30..240 deg with a 60 deg field cover 0..270 deg: the 90 deg band left is
    25 % of the wall (tolerance 2 percentage points), the same in every segment."""
    poses = tube_views(np.arange(0, 0.1001, 0.004), np.arange(30, 241, 15))
    cov = compute_coverage(tube_mesh(), poses, CAM.K, VIEW, CFG)
    assert cov.unseen_share() == pytest.approx(0.25, abs=0.02)
    segs = cov.segments(0.025)
    assert len(segs) == 4 and all(seg["unseen_share"] == pytest.approx(0.25, abs=0.02) for seg in segs)
    theta, half = cov.wall.theta_centres, cov.wall.cell_angle / 2
    band = (theta > -np.pi / 2 + half) & (theta < 0)  # 270..360 deg, cells wholly inside
    outside = (theta > half) | (theta < -np.pi / 2 - half)
    assert (~cov.observed[:, band]).all() and cov.observed[:, outside].all()


def _forward(fold: bool, drop=None):
    cam = PinholeCamera.from_fov(48, 48, 110.0)
    view = ViewSettings(cam.width, cam.height, 0.001, 0.2)
    mesh = tube_mesh(fold=(S0, 0.4, SIGMA) if fold else None, drop=drop)
    return compute_coverage(mesh, tube_views(np.arange(0, 0.1001, 0.002)), cam.K, view, CFG)


@pytest.mark.parametrize("hole", [False, True], ids=["complete-surface", "hole-behind-fold"])
def test_fold_hides_the_wall_behind_it(hole):
    """Cameras on the axis looking forward: the back of the fold is unseen, the wall before it
    seen; without the fold the same band is seen. With the hidden wall missing from the
    surface (as fusion leaves it) the filled-in wall model still comes out unseen there."""
    drop = (lambda z, th: (z > S0 + SIGMA) & (z < S0 + 3 * SIGMA)) if hole else None
    cov = _forward(True, drop)
    behind, before = _rows(cov, S0 + 0.5 * SIGMA, S0 + 2 * SIGMA), _rows(cov, S0 - 0.03, S0 - 0.01)
    assert cov.unseen_share(behind) > 0.9
    assert cov.unseen_share(before) < 0.05
    if hole:
        assert not cov.wall.measured[_rows(cov, S0 + 1.2 * SIGMA, S0 + 2.8 * SIGMA)].any()
    plain = _forward(False)
    assert plain.unseen_share(_rows(plain, S0 + 0.5 * SIGMA, S0 + 2 * SIGMA)) < 0.05
