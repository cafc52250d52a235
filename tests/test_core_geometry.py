"""NumPy geometry (c3f_slam.geometry) against hand-computed cases."""

import math

import numpy as np
import pytest
from numpy.testing import assert_allclose

from c3f_core.errors import InputError
from c3f_slam import geometry as g
from c3f_slam.camera.intrinsics import PinholeCamera


def test_axis_angle_quarter_turn_about_z():
    R = g.axis_angle_to_matrix([0, 0, math.pi / 2])
    # x axis goes to y, y to -x (hand computed)
    assert_allclose(R @ [1, 0, 0], [0, 1, 0], atol=1e-12)
    assert_allclose(R @ [0, 1, 0], [-1, 0, 0], atol=1e-12)
    assert_allclose(g.matrix_to_axis_angle(R), [0, 0, math.pi / 2], atol=1e-12)


@pytest.mark.parametrize("vec", [[0.1, -0.2, 0.3], [1e-9, 0, 0], [0, 3.0, 0.1], [2.0, -1.0, 0.5]])
def test_axis_angle_round_trip(vec):
    R = g.axis_angle_to_matrix(vec)
    assert g.is_rotation(R)
    assert_allclose(g.axis_angle_to_matrix(g.matrix_to_axis_angle(R)), R, atol=1e-10)


def test_quaternion_known_values_and_round_trip():
    # 180 degrees about x: q = (1, 0, 0, 0) in (x, y, z, w)
    assert_allclose(g.quaternion_to_matrix([1, 0, 0, 0]), np.diag([1, -1, -1]), atol=1e-12)
    rng = np.random.default_rng(0)
    for _ in range(20):
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        q = q if q[3] >= 0 else -q
        assert_allclose(g.matrix_to_quaternion(g.quaternion_to_matrix(q)), q, atol=1e-10)


def test_invert_and_compose():
    T = g.make_pose(g.axis_angle_to_matrix([0.3, -0.1, 0.2]), [1.0, 2.0, -0.5])
    assert_allclose(g.compose(T, g.invert_pose(T)), np.eye(4), atol=1e-12)
    # hand case: translation only
    Tt = g.make_pose(np.eye(3), [1, 2, 3])
    assert_allclose(g.invert_pose(Tt)[:3, 3], [-1, -2, -3])
    # relative pose: T_ij maps j into i
    Ta = g.make_pose(np.eye(3), [1, 0, 0])
    Tb = g.make_pose(np.eye(3), [0, 0, 2])
    assert_allclose(g.relative_pose(Ta, Tb)[:3, 3], [-1, 0, 2])


def test_project_backproject_hand_case():
    K = np.array([[100.0, 0, 50], [0, 100.0, 40], [0, 0, 1]])
    uv, z = g.project(np.array([[0.1, -0.2, 2.0]]), K)
    # u = 100*0.1/2 + 50 = 55, v = 100*-0.2/2 + 40 = 30
    assert_allclose(uv, [[55.0, 30.0]])
    assert_allclose(z, [2.0])
    pts = g.backproject_pixels(uv, z, K)
    assert_allclose(pts, [[0.1, -0.2, 2.0]])
    depth = np.full((80, 100), 2.0)
    grid = g.backproject(depth, K)
    assert_allclose(grid[30, 55], [0.1, -0.2, 2.0])
    uv_behind, _ = g.project(np.array([[0.0, 0.0, -1.0]]), K)
    assert np.isnan(uv_behind).all()


def test_look_at_points_camera_at_target():
    T = g.look_at([0, 0, 0], [0, 0, 5], up=[0, -1, 0])
    assert g.is_rotation(T[:3, :3])
    assert_allclose(T[:3, 2], [0, 0, 1], atol=1e-12)
    assert_allclose(T[:3, :3], np.eye(3), atol=1e-12)  # up = -y in the world -> identity


def test_camera_crop_resize_follow_pixels():
    cam = PinholeCamera(512, 512, 200.0, 200.0, 255.5, 255.5)
    x0, y0, w, h = cam.center_crop_box(400, 400)
    assert (x0, y0, w, h) == (56, 56, 400, 400)
    c2 = cam.crop(x0, y0, w, h).resize(224, 224)
    # a 3D point projects to the same place before and after, mapped by the crop+resize
    p = np.array([[0.01, -0.02, 0.05]])
    uv_full, _ = g.project(p, cam.K)
    uv_small, _ = g.project(p, c2.K)
    s = 224 / 400
    expected = (uv_full - [x0, y0] + 0.5) * s - 0.5
    assert_allclose(uv_small, expected, atol=1e-9)
    with pytest.raises(InputError, match="larger than the image"):
        cam.center_crop_box(600, 100)


def test_camera_validation_and_fov():
    with pytest.raises(InputError, match="fx"):
        PinholeCamera(10, 10, -1.0, 1.0, 5, 5)
    with pytest.raises(InputError, match="field of view"):
        PinholeCamera.from_fov(64, 64, 180.0)
    cam = PinholeCamera.from_fov(256, 256, 120.0)
    assert cam.fov_deg()[0] == pytest.approx(120.0)
