"""Frustum overlap between frames (fragment condition (2))."""

from __future__ import annotations

import numpy as np
import pytest

from c3f_slam import geometry as g
from c3f_slam.camera.frustum import frustum_overlap, grid_pixels
from c3f_slam.camera.intrinsics import PinholeCamera

CAM = PinholeCamera.from_fov(64, 48, 90.0)
PLANE = 0.05  # metres: the plane z = 5 cm, fronto-parallel to the first camera


def _plane_depth(T_wc: np.ndarray) -> np.ndarray:
    """Exact depth of the world plane z = PLANE seen from a camera with pose T_wc."""
    u, v = np.meshgrid(np.arange(CAM.width), np.arange(CAM.height))
    rays = np.stack([u, v, np.ones_like(u)], -1).reshape(-1, 3) @ np.linalg.inv(CAM.K).T
    rw = rays @ T_wc[:3, :3].T
    s = (PLANE - T_wc[2, 3]) / rw[:, 2]
    d = np.where(s > 0, s, 0.0)  # ray z-component is 1, so depth = s
    return d.reshape(CAM.height, CAM.width)


def test_grid_pixels():
    uv = grid_pixels(8, 4, 4)
    assert uv.tolist() == [[2, 2], [6, 2]]
    with pytest.raises(ValueError):
        grid_pixels(8, 8, 0)


def test_self_overlap_is_full():
    T = g.make_pose(g.axis_angle_to_matrix([0.1, 0.2, 0.0]), [0.01, 0.0, -0.01])
    d = _plane_depth(T)
    assert frustum_overlap(d, CAM.K, T, T) == 1.0
    assert frustum_overlap(d, CAM.K, T, T, depth_j=d) == 1.0


def test_turned_away_is_zero():
    T0 = np.eye(4)
    T_back = g.make_pose(g.axis_angle_to_matrix([0.0, np.pi, 0.0]), [0.0, 0.0, 0.0])
    assert frustum_overlap(_plane_depth(T0), CAM.K, T0, T_back) == 0.0


def test_sideways_shift_gives_half():
    """At 5 cm a 90-degree camera sees 10 cm across; a 2.5 cm shift keeps ~3/4, 5 cm keeps ~1/2."""
    T0 = np.eye(4)
    d0 = _plane_depth(T0)
    for shift, expected in ((0.025, 0.75), (0.05, 0.5), (0.12, 0.0)):
        T1 = g.make_pose(np.eye(3), [shift, 0.0, 0.0])
        ov = frustum_overlap(d0, CAM.K, T0, T1, stride=2)
        assert ov == pytest.approx(expected, abs=0.04), shift


def test_scalar_depth_and_depth_consistency():
    T0 = np.eye(4)
    T1 = g.make_pose(np.eye(3), [0.025, 0.0, 0.0])
    d0 = _plane_depth(T0)
    full = frustum_overlap(PLANE, CAM.K, T0, T1, size_i=(CAM.width, CAM.height), stride=2)
    assert full == pytest.approx(frustum_overlap(d0, CAM.K, T0, T1, stride=2), abs=1e-9)
    # consistent depth in frame j keeps the overlap; a wall 2 cm in front of frame j occludes it
    assert frustum_overlap(d0, CAM.K, T0, T1, depth_j=_plane_depth(T1), stride=2) == pytest.approx(full, abs=0.02)
    occluder = np.full((CAM.height, CAM.width), 0.03)
    assert frustum_overlap(d0, CAM.K, T0, T1, depth_j=occluder, stride=2) == 0.0


def test_no_valid_depth():
    assert frustum_overlap(np.zeros((CAM.height, CAM.width)), CAM.K, np.eye(4), np.eye(4)) == 0.0
    with pytest.raises(ValueError):
        frustum_overlap(0.05, CAM.K, np.eye(4), np.eye(4))  # scalar depth needs size_i
