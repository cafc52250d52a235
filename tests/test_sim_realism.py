"""The realism statistic of simulated against real frames (benchmarks.common.realism) on small
synthetic frames: identity ~0, blur and colour shifts move it, order does not."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from benchmarks.common.realism import (
    DIAGNOSTICS,
    TERMS,
    descriptor,
    descriptor_distances,
    nearest_distances,
    noise_sigma,
    realism,
    realism_distance,
    static_border,
)


def textured(n: int = 6, size: int = 48, seed: int = 0) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        small = rng.integers(40, 220, (8, 8, 3)).astype(np.uint8)
        img = cv2.resize(small, (size, size), interpolation=cv2.INTER_CUBIC).astype(np.float32)
        img += rng.normal(0, 4, img.shape)
        out.append(np.clip(img, 0, 255).astype(np.uint8))
    return out


def test_identical_sets_give_zero():
    fs = textured()
    s = realism(fs, fs, size=48)
    assert set(s) == {*TERMS, *DIAGNOSTICS, "total"}
    assert all(abs(s[t]) < 1e-3 for t in s)
    assert s["total"] == pytest.approx(np.mean([s[t] for t in TERMS]))


def test_order_does_not_matter():
    a, b = textured(seed=1), textured(seed=2)
    assert realism_distance(a, b, size=48) == pytest.approx(realism_distance(a[::-1], b[::-1], size=48), abs=1e-6)


def test_blur_and_colour_shift_increase_it():
    fs = textured()
    blurred = [cv2.GaussianBlur(f, (0, 0), 2.0) for f in fs]
    shifted = [np.clip(f.astype(int) + [40, 0, -30], 0, 255).astype(np.uint8) for f in fs]
    base = realism(fs, fs, size=48)
    sb, sc = realism(blurred, fs, size=48), realism(shifted, fs, size=48)
    assert sb["gradient"] > base["gradient"] + 0.01 and sb["noise"] > base["noise"] + 0.01
    assert sc["colour"] > base["colour"] + 0.05
    assert sb["total"] > base["total"] and sc["total"] > base["total"]
    # a stronger shift is farther
    more = [np.clip(f.astype(int) + [80, 0, -60], 0, 255).astype(np.uint8) for f in fs]
    assert realism(more, fs, size=48)["colour"] > sc["colour"]


def test_masks_leave_the_border_out_and_sizes_may_differ():
    fs = textured()
    bordered = []
    for f in fs:
        g = f.copy()
        g[:, :8] = 0
        bordered.append(g)
    mask = static_border(bordered, erode_px=0)
    assert not mask[:, :8].any() and mask[:, 8:].all()
    inner = [f[:, 8:] for f in fs]
    with_mask = realism(inner, bordered, real_masks=mask, size=40)
    without = realism(inner, bordered, size=40)
    assert with_mask["colour"] < without["colour"]
    big = [cv2.resize(f, (96, 96), interpolation=cv2.INTER_CUBIC) for f in fs]
    assert realism(big, fs, size=48)["colour"] < 0.02  # compared at one scale


def test_noise_sigma_tracks_added_noise():
    rng = np.random.default_rng(3)
    flat = np.full((64, 64, 3), 120, np.uint8)
    est = [noise_sigma(np.clip(flat + rng.normal(0, s, flat.shape), 0, 255).astype(np.uint8)) for s in (2, 5, 10)]
    assert est[0] < est[1] < est[2]
    assert 6 < est[2] < 14  # about the std of the luminance noise added (grey levels)


def shift(frames: list[np.ndarray], rgb: tuple[int, int, int]) -> list[np.ndarray]:
    return [np.clip(f.astype(int) + rgb, 0, 255).astype(np.uint8) for f in frames]


def test_descriptor_distance_is_a_bounded_hellinger_mean():
    fs = textured(4)
    d = np.stack([descriptor(f, np.ones(f.shape[:2], bool)) for f in fs])
    m = descriptor_distances(d, d)
    assert m.shape == (4, 4) and np.allclose(np.diag(m), 0.0, atol=1e-6) and np.allclose(m, m.T)
    assert (m >= 0).all() and (m <= 1).all()
    far = descriptor_distances(d[:1], np.stack([descriptor(f, np.ones(f.shape[:2], bool))
                                                for f in shift(fs[:1], (90, -60, -60))]))
    assert far[0, 0] > m[0, 1:].max()  # a strong colour change is farther than another texture


def test_nearest_is_a_per_frame_mean_that_does_not_punish_variety():
    """Each simulated frame is scored against its nearest real frames: a set that mixes a look like
    the real one with another look scores the weighted mean of the two (no penalty for mixing),
    and the frames like the real ones score ~0 inside it, while the spread-matching Frechet
    distance grows with the mix."""
    real = textured(8, seed=0)
    like = textured(6, seed=0)[:3] + textured(3, seed=7)
    other = shift(textured(6, seed=5), (70, -40, -50))
    per = nearest_distances(like + other, real, size=48)
    assert per.shape == (12,) and ((per >= 0) & (per <= 1)).all()
    assert np.allclose(per[:3], 0.0, atol=1e-6)  # copies of real frames
    assert per[6:].min() > per[:6].max()  # the other look is farther, frame by frame
    mixed, alone = realism(like + other, real, size=48), realism(like, real, size=48)
    assert mixed["nearest"] == pytest.approx(per.mean(), abs=1e-9)
    assert mixed["nearest"] == pytest.approx((6 * alone["nearest"] + 6 * per[6:].mean()) / 12, abs=1e-9)
    assert mixed["frechet"] > alone["frechet"]


def test_nearest_grows_with_the_colour_shift():
    real = textured(6, seed=2)
    near = [nearest_distances(shift(real, (s, 0, -s)), real, size=48).mean() for s in (0, 20, 60)]
    assert near[0] < 1e-6 < near[1] < near[2]
