"""Depth metrics (c3f_slam.evaluation.depth.depth_metrics) against values computed by hand."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from c3f_slam.evaluation.depth import METRIC_NAMES, depth_metrics

GT = np.array([[0.01, 0.02], [0.04, 0.05]])  # metres
PRED = np.array([[0.01, 0.01], [0.052, 0.05]])

# by hand: differences gt - pred = 0, 0.01, -0.012, 0; ratios max(gt/pred, pred/gt) = 1, 2, 1.3, 1
HAND = {
    "abs_rel": (0 + 0.01 / 0.02 + 0.012 / 0.04 + 0) / 4,  # 0.2
    "sq_rel": (0 + 1e-4 / 0.02 + 0.012**2 / 0.04 + 0) / 4,  # 0.00215 m
    "rmse": math.sqrt((1e-4 + 0.012**2) / 4),  # 0.00781 m
    "rmse_log": math.sqrt((math.log(2) ** 2 + math.log(1.3) ** 2) / 4),
    "a1": 2 / 4,  # 1.3 and 2 are not < 1.25
    "a2": 3 / 4,  # 1.3 < 1.5625
    "a3": 3 / 4,  # 2 is not < 1.953
}


def test_hand_computed_2x2_without_scaling():
    m = depth_metrics(PRED, GT, median_scaling=False, min_depth=1e-3, max_depth=0.3)
    for k, v in HAND.items():
        assert m[k] == pytest.approx(v, rel=1e-9), k
    assert m["n_images"] == 1


def test_median_scaling_per_image_and_mean_over_images():
    # median(PRED) = (0.01 + 0.05) / 2 = median(GT) = 0.03: scaled by the median ratio, PRED comes back
    for factor in (2.0, 7.0, 0.01):  # so any scale of PRED gives the hand values
        m = depth_metrics(PRED * factor, GT, median_scaling=True)
        for k, v in HAND.items():
            assert m[k] == pytest.approx(v, rel=1e-9), (factor, k)
    # averaged over images: image 0 the hand case up to scale, image 1 perfect up to scale
    m = depth_metrics(np.stack([PRED * 3.0, GT * 0.5]), np.stack([GT, GT]), median_scaling=True)
    for k, v in HAND.items():
        perfect = 1.0 if k in ("a1", "a2", "a3") else 0.0
        assert m[k] == pytest.approx((v + perfect) / 2, rel=1e-9, abs=1e-12), k
    assert m["n_images"] == 2


def test_torch_input_mask_and_depth_range():
    gt = torch.tensor(GT, dtype=torch.float32)[None, None]
    pred = torch.tensor(PRED, dtype=torch.float32)[None, None]
    m_np = depth_metrics(PRED, GT, median_scaling=False)
    m_t = depth_metrics(pred, gt, median_scaling=False)
    for k in METRIC_NAMES:
        assert m_t[k] == pytest.approx(m_np[k], rel=1e-5)
    # masking out the two wrong pixels leaves a perfect image
    mask = np.array([[True, False], [False, True]])
    m = depth_metrics(PRED, GT, mask=mask, median_scaling=False)
    assert m["abs_rel"] == 0 and m["a1"] == 1
    # gt = 0 (no depth) and gt beyond max_depth are ignored
    gt0 = GT.copy()
    gt0[0, 1] = 0.0
    gt0[1, 0] = 0.5
    m = depth_metrics(PRED, gt0, median_scaling=False, max_depth=0.3)
    assert m["abs_rel"] == 0
    # an image without valid pixels is skipped; none at all gives NaN
    m = depth_metrics(np.stack([PRED, PRED]), np.stack([GT, np.zeros_like(GT)]), median_scaling=False)
    assert m["n_images"] == 1 and m["abs_rel"] == pytest.approx(HAND["abs_rel"])
    assert math.isnan(depth_metrics(PRED, np.zeros_like(GT))["rmse"])


def test_prediction_is_clipped_to_range_after_scaling():
    gt = np.full((2, 2), 0.02)
    pred = np.array([[1.0, 1.0], [1.0, 100.0]])  # scaled by 0.02 -> one pixel at 2 m, clipped to 0.3
    m = depth_metrics(pred, gt, median_scaling=True, max_depth=0.3)
    assert m["rmse"] == pytest.approx(math.sqrt((0.3 - 0.02) ** 2 / 4))


def test_shape_errors():
    with pytest.raises(ValueError):
        depth_metrics(np.zeros((2, 2)), np.zeros((3, 3)))
    with pytest.raises(ValueError):
        depth_metrics(np.zeros((1, 3, 2, 2)), np.zeros((1, 3, 2, 2)))


def test_coefficient_of_variation_flags_a_flat_prediction():
    flat = np.full_like(GT, 0.02)
    m = depth_metrics(flat, GT, median_scaling=True)
    assert m["pred_cv"] == pytest.approx(0.0, abs=1e-12)
    assert m["gt_cv"] == pytest.approx(np.std(GT) / np.mean(GT), rel=1e-9)
    # scale-free: any multiple of the ground truth has the ground truth's CV
    assert depth_metrics(GT * 5.0, GT)["pred_cv"] == pytest.approx(m["gt_cv"], rel=1e-9)


def test_scale_is_the_median_gt_to_prediction_ratio():
    rng = np.random.default_rng(3)
    gt = rng.uniform(0.01, 0.1, (3, 8, 8))
    pred = gt / np.array([4.0, 5.0, 7.0])[:, None, None]  # per-image scale 4, 5 and 7
    m = depth_metrics(pred, gt)
    assert m["scale"] == pytest.approx(5.0, rel=1e-9)
    assert m["abs_rel"] == pytest.approx(0.0, abs=1e-12)  # median scaling undoes it
    assert np.isnan(depth_metrics(np.zeros((4, 4)), np.zeros((4, 4)))["scale"])
