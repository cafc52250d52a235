"""Torch geometry (c3f_models.geometry): hand cases, parity with the NumPy half, warping."""

import math

import numpy as np
import torch
from torch.testing import assert_close

from c3f_models import geometry as tg
from c3f_slam import geometry as g
from c3f_slam.camera.intrinsics import PinholeCamera
from tests.scenes import plane_texture, render_plane

TOL = dict(atol=1e-5, rtol=1e-5)


def test_backproject_project_hand_case():
    K = torch.tensor([[[100.0, 0, 50], [0, 100.0, 40], [0, 0, 1]]])
    depth = torch.full((1, 1, 80, 100), 2.0)
    pts = tg.backproject(depth, K)
    assert_close(pts[0, :, 30, 55], torch.tensor([0.1, -0.2, 2.0]), **TOL)
    uv, z = tg.project(pts, K)
    assert_close(uv[0, :, 30, 55], torch.tensor([55.0, 30.0]), **TOL)
    assert_close(z, depth)


def test_axis_angle_and_pose_match_numpy():
    aa = torch.tensor([[0.3, -0.2, 0.1], [0.0, 0.0, math.pi / 2]], dtype=torch.float64)
    t = torch.tensor([[0.01, 0.02, -0.03], [1.0, 0.0, 0.0]], dtype=torch.float64)
    T = tg.pose_from_axis_angle(aa, t)
    for k in range(2):
        ref = g.make_pose(g.axis_angle_to_matrix(aa[k].numpy()), t[k].numpy())
        assert_close(T[k], torch.from_numpy(ref), atol=1e-12, rtol=0)
    assert_close(T @ tg.invert_pose(T), torch.eye(4, dtype=torch.float64).expand(2, 4, 4), atol=1e-12, rtol=0)


def test_warp_is_exact_on_a_plane():
    """Warping a rendered source view with true depth and pose reproduces the target."""
    cam = PinholeCamera.from_fov(64, 64, 90.0)
    tex = plane_texture(seed=3)
    T_wt = g.make_pose(np.eye(3), [0.0, 0.0, 0.0])
    T_ws = g.make_pose(g.axis_angle_to_matrix([0.0, 0.02, 0.0]), [0.003, 0.001, 0.0])
    img_t, depth_t = render_plane(cam, T_wt, tex, 0.05, 0.1)
    img_s, depth_s = render_plane(cam, T_ws, tex, 0.05, 0.1)
    to_t = lambda a: torch.from_numpy(np.ascontiguousarray(a)).permute(2, 0, 1)[None].float() / 255
    K = torch.from_numpy(cam.K).float()[None]
    T_st = torch.from_numpy(g.relative_pose(T_ws, T_wt)).float()[None]
    d_t = torch.from_numpy(depth_t)[None, None]
    d_s = torch.from_numpy(depth_s)[None, None]
    w = tg.warp(to_t(img_s), d_t, T_st, K, source_depth=d_s)
    err = (w.image - to_t(img_t)).abs().mean(1, keepdim=True)[w.valid]
    assert w.valid.float().mean() > 0.8
    assert float(err.mean()) < 0.01
    # consistent depths: the depth seen from the source equals the source depth sampled there
    rel = ((w.sampled_depth - w.projected_depth).abs() / w.projected_depth)[w.valid]
    assert float(rel.max()) < 1e-3
    # a wrong pose gives a much larger error
    T_bad = torch.from_numpy(g.relative_pose(T_ws, g.make_pose(np.eye(3), [0.004, 0, 0]))).float()[None]
    wb = tg.warp(to_t(img_s), d_t, T_bad, K)
    err_bad = (wb.image - to_t(img_t)).abs().mean(1, keepdim=True)[wb.valid]
    assert float(err_bad.mean()) > 5 * float(err.mean())
