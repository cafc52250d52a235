"""DepthNet losses on hand-made cases and on an analytic plane triplet (exact depth and poses)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from c3f_models.depth import losses as lo
from c3f_models.depth.objective import (
    EXTRA_PAIRS,
    LossConfig,
    SelfSupervisedLoss,
    compose_triplet_poses,
)
from c3f_models.geometry import invert_pose, pose_from_axis_angle, warp
from c3f_slam import geometry as g
from c3f_slam.camera.intrinsics import PinholeCamera
from tests.scenes import plane_texture, render_plane

SIZE = 64


def _img(a: np.ndarray) -> torch.Tensor:
    return torch.from_numpy(np.ascontiguousarray(a)).permute(2, 0, 1)[None].float() / 255


def plane_triplet(step: float = 0.002, seed: int = 1):
    """Frames (t-1, t, t+1) of a textured plane 5 cm away, camera moving sideways and turning."""
    cam = PinholeCamera.from_fov(SIZE, SIZE, 90.0)
    tex = plane_texture(seed=seed)
    T_w = [g.make_pose(g.axis_angle_to_matrix([0.0, 0.01 * k, 0.0]), [step * k, 0.0005 * k, 0.0]) for k in range(3)]
    images, depths = [], {}
    for k, T in enumerate(T_w):
        rgb, depth = render_plane(cam, T, tex, 0.05, 0.1)
        images.append(_img(rgb))
        depths[k] = torch.from_numpy(depth)[None, None]
    poses = {(i, j): torch.from_numpy(g.relative_pose(T_w[i], T_w[j])).float()[None]
             for i in range(3) for j in range(3) if i != j}
    K = torch.from_numpy(cam.K).float()[None]
    return images, depths, poses, K


def no_specular(images):
    return [torch.zeros_like(im[:, :1], dtype=torch.bool) for im in images]


def score(cfg: LossConfig, images, depths, poses, K, specular=None):
    """The objective with depths given directly (identity disparity -> depth, one scale)."""
    specular = no_specular(images) if specular is None else specular
    return SelfSupervisedLoss(cfg)(images, specular, {k: [d] for k, d in depths.items()}, lambda d: d, poses, K)


# ---------------------------------------------------------------- building blocks
def test_photometric_error_of_image_with_itself_is_zero():
    x = torch.rand(2, 3, 16, 16)
    pe = lo.photometric_error(x, x)
    assert pe.shape == (2, 1, 16, 16)
    assert float(pe.abs().max()) < 1e-5
    y = (x + 0.3).clamp(0, 1)
    assert float(lo.photometric_error(y, x).mean()) > 0.05


def test_photometric_error_weights_ssim_and_l1():
    x = torch.full((1, 3, 8, 8), 0.2)
    y = torch.full((1, 3, 8, 8), 0.6)  # flat images: SSIM term only from the means
    l1 = 0.4
    mu_x, mu_y = 0.2, 0.6
    ssim = (2 * mu_x * mu_y + lo.SSIM_C1) / (mu_x**2 + mu_y**2 + lo.SSIM_C1)
    expected = 0.85 * (1 - ssim) / 2 + 0.15 * l1
    assert torch.allclose(lo.photometric_error(y, x), torch.tensor(expected), atol=1e-4)


def test_automask_drops_static_pixels():
    """Source == target: the unwarped source is already perfect, so every pixel is masked."""
    images, depths, poses, K = plane_triplet()
    static = [images[1]] * 3
    eye = {k: torch.eye(4)[None] for k in poses}
    terms = score(LossConfig(), static, {k: depths[1] for k in range(3)}, eye, K)
    assert not terms.automask.any()
    assert float(terms.loss) == 0.0
    # the same frames with real motion keep most pixels
    terms = score(LossConfig(), images, depths, poses, K)
    assert terms.automask.float().mean() > 0.5
    assert bool(lo.automask(torch.tensor([0.1]), torch.tensor([0.2])))
    assert not bool(lo.automask(torch.tensor([0.2]), torch.tensor([0.2])))  # ties go to the identity


def test_percentile_mask_keeps_80_percent():
    err = torch.randperm(100).float().view(1, 1, 10, 10)
    valid = torch.ones_like(err, dtype=torch.bool)
    keep = lo.percentile_mask(err, valid, 0.8)
    assert int(keep.sum()) == 80
    assert float(err[keep].max()) == 79.0
    # per image, over valid pixels only
    valid[:, :, :5] = False
    err2 = torch.cat([err, err * 10])
    keep2 = lo.percentile_mask(err2, torch.cat([valid, valid]), 0.8)
    assert int(keep2[0].sum()) == int(keep2[1].sum()) == 40
    assert not keep2[:, :, :5].any()


def test_depth_consistency_zero_for_consistent_depths():
    d = torch.rand(1, 1, 4, 4) + 0.01
    assert float(lo.depth_consistency_error(d, d).abs().max()) == 0.0
    assert torch.allclose(lo.depth_consistency_error(torch.tensor(3.0), torch.tensor(1.0)), torch.tensor(0.5))
    # on the plane, true depths are consistent across all pairs of S
    images, depths, poses, K = plane_triplet()
    for i, j in EXTRA_PAIRS:
        w = warp(images[j], depths[i], poses[(j, i)], K, source_depth=depths[j])
        err = lo.depth_consistency_error(w.projected_depth, w.sampled_depth)[w.valid]
        assert float(err.max()) < 1e-3


def test_min_over_sources_and_masked_mean():
    errors = torch.tensor([1.0, 5.0, 2.0]).view(3, 1, 1, 1, 1).expand(3, 1, 1, 1, 2).clone()
    valid = torch.ones_like(errors, dtype=torch.bool)
    valid[0, ..., 1] = False
    m, anyv = lo.min_over_sources(errors, valid)
    assert m.flatten().tolist() == [1.0, 2.0] and anyv.all()
    assert float(lo.masked_mean(torch.tensor([1.0, 3.0, 100.0]), torch.tensor([True, True, False]))) == 2.0
    assert float(lo.masked_mean(torch.tensor([1.0]), torch.tensor([False]))) == 0.0


def test_pose_composition_of_a_triplet():
    aa = torch.tensor([[0.01, -0.02, 0.03], [0.02, 0.01, -0.01]])
    t = torch.tensor([[0.001, 0.002, -0.001], [0.003, 0.0, 0.001]])
    T = pose_from_axis_angle(aa, t)
    poses = compose_triplet_poses(T[:1], T[1:])
    assert torch.allclose(poses[(2, 0)], T[1:] @ T[:1], atol=1e-6)
    for (i, j), T_ij in poses.items():
        assert torch.allclose(T_ij @ poses[(j, i)], torch.eye(4)[None], atol=1e-6)
    # chain rule: T_02 = T_01 T_12
    assert torch.allclose(poses[(0, 2)], poses[(0, 1)] @ poses[(1, 2)], atol=1e-6)


# ---------------------------------------------------------------- the objective on a plane
def test_true_depth_and_pose_give_near_zero_reprojection_error():
    images, depths, poses, K = plane_triplet()
    plain = LossConfig(use_outlier_mask=False, use_automask=False)  # warped pixels only
    good = score(plain, images, depths, poses, K)
    assert float(good.ph) < 0.02
    assert float(good.ph_extra) < 0.02
    assert float(good.dc) < 1e-3
    # wrong poses: camera motion reversed
    bad_poses = compose_triplet_poses(invert_pose(poses[(1, 0)]), invert_pose(poses[(2, 1)]))
    bad = score(plain, images, depths, bad_poses, K)
    assert float(bad.ph) > 4 * float(good.ph)
    assert float(bad.ph_extra) > 4 * float(good.ph_extra)
    # with the auto-mask, masked pixels carry the identity error: still a clear gap
    good_mu = score(LossConfig(), images, depths, poses, K)
    bad_mu = score(LossConfig(), images, depths, bad_poses, K)
    assert float(bad_mu.loss) > 2 * float(good_mu.loss)
    assert good_mu.automask.float().mean() > 0.5 > bad_mu.automask.float().mean()
    # wrong depth (not a scaled copy): the consistency term notices
    ramp = torch.linspace(0, 1, SIZE).view(1, 1, 1, -1)
    warped_depths = {k: d * (1 + 0.5 * ramp * (k - 1)) for k, d in depths.items()}
    assert float(score(LossConfig(), images, warped_depths, poses, K).dc) > 10 * float(good.dc)


def test_switches_turn_terms_off():
    images, depths, poses, K = plane_triplet()
    md2 = LossConfig(use_extra_photometric=False, use_depth_consistency=False, use_outlier_mask=False,
                     use_specular_mask=False)
    terms = score(md2, images, {1: depths[1]}, poses, K)  # Monodepth2 needs only the centre depth
    assert terms.ph_extra is None and terms.dc is None
    assert torch.equal(terms.loss, terms.ph)
    full = score(LossConfig(), images, depths, poses, K)
    expected = full.ph + 0.1 * full.ph_extra + 0.1 * full.dc
    assert torch.allclose(full.loss, expected)
    # outlier removal lowers the mean photometric error (it drops the worst 20 %)
    no_out = score(LossConfig(use_outlier_mask=False), images, depths, poses, K)
    assert float(full.ph) < float(no_out.ph)


@pytest.mark.parametrize("frame", [0, 1, 2])
def test_specular_pixels_do_not_change_the_loss(frame):
    images, depths, poses, K = plane_triplet()
    spec = no_specular(images)
    spec = [s.clone() for s in spec]
    spec[frame][..., 18:46, 18:46] = True
    base = score(LossConfig(), images, depths, poses, K, spec)
    changed = [im.clone() for im in images]
    changed[frame][..., 22:42, 22:42] = torch.rand(1, 3, 20, 20)  # inside the mask, 4 px from its edge
    after = score(LossConfig(), changed, depths, poses, K, spec)
    for name in ("loss", "ph", "ph_extra", "dc"):
        assert torch.allclose(getattr(base, name), getattr(after, name), atol=1e-7), name
    # without the specular mask the same change does alter the loss
    off = LossConfig(use_specular_mask=False)
    before = score(off, images, depths, poses, K, spec).loss
    assert not torch.allclose(before, score(off, changed, depths, poses, K, spec).loss)


def test_loss_is_differentiable_in_depth_and_pose():
    images, depths, poses, K = plane_triplet()
    depths = {k: (d * 1.1).requires_grad_() for k, d in depths.items()}
    aa = torch.zeros(2, 3, requires_grad=True)
    t = torch.tensor([[0.002, 0.0, 0.0], [0.002, 0.0, 0.0]], requires_grad=True)
    T = pose_from_axis_angle(aa, t)
    terms = score(LossConfig(), images, depths, compose_triplet_poses(T[:1], T[1:]), K)
    terms.loss.backward()
    for k in range(3):
        assert depths[k].grad is not None and torch.isfinite(depths[k].grad).all()
        assert depths[k].grad.abs().sum() > 0
    assert t.grad.abs().sum() > 0 and aa.grad.abs().sum() > 0


def test_no_motion_is_no_trivial_optimum():
    """Auto-masked pixels keep their identity error, so predicting no motion does not pay."""
    images, depths, poses, K = plane_triplet()
    eye = {k: torch.eye(4)[None] for k in poses}
    true = score(LossConfig(), images, depths, poses, K)
    still = score(LossConfig(), images, depths, eye, K)
    assert still.automask.float().mean() < 0.5 < true.automask.float().mean()  # ties up to float noise
    assert float(still.ph) > 2 * float(true.ph)
    assert float(still.ph_extra) > 2 * float(true.ph_extra)
