"""Seeded random streams and smooth noise fields (NumPy/OpenCV, deterministic).

Every random draw of the simulator comes from :func:`stream`, a NumPy ``Generator`` keyed by
the user's seed and a fixed stream number, so the geometry does not change when, e.g., only
the number of frames changes, and nothing depends on time or on the order of the frames.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
from scipy.ndimage import gaussian_filter1d

# stream numbers (never reuse one for a different purpose)
GEOMETRY, TEXTURE, PATH, FRAME = 1, 2, 3, 4


def stream(seed: int, *key: int) -> np.random.Generator:
    """Independent generator for (seed, key...)."""
    return np.random.default_rng(np.random.SeedSequence(entropy=int(seed), spawn_key=tuple(int(k) for k in key)))


def smooth_1d(rng: np.random.Generator, n: int, corr: float) -> np.ndarray:
    """(n,) zero-mean noise with unit std, Gaussian-correlated over ``corr`` samples."""
    if n <= 0:
        return np.zeros(0)
    corr = max(float(corr), 1e-3)
    pad = int(3 * corr) + 1
    white = rng.standard_normal(n + 2 * pad)
    out = gaussian_filter1d(white, corr, mode="reflect")[pad : pad + n]
    return out * math.sqrt(2.0 * math.sqrt(math.pi) * corr) if corr >= 0.5 else out


def random_sines(rng: np.random.Generator, x: np.ndarray, wavelengths: tuple[float, float], count: int) -> np.ndarray:
    """Sum of ``count`` sines of x with random wavelengths and phases, scaled to |.| <= 1."""
    out = np.zeros_like(x, dtype=np.float64)
    amps = rng.uniform(0.5, 1.0, count)
    lam = rng.uniform(*wavelengths, count)
    ph = rng.uniform(0, 2 * np.pi, count)
    for amp, wavelength, phase in zip(amps, lam, ph):
        out += amp * np.sin(2 * np.pi * x / wavelength + phase)
    return out / amps.sum()


def wrap_rows_blur(img: np.ndarray, sigma: float) -> np.ndarray:
    """Gaussian blur that wraps around in rows (the angle around the colon), reflects in columns."""
    if sigma <= 0:
        return img
    k = int(2 * math.ceil(3 * sigma) + 1)
    pad = k // 2
    padded = cv2.copyMakeBorder(img, pad, pad, 0, 0, cv2.BORDER_WRAP)
    out = cv2.GaussianBlur(padded, (k, k), sigma, borderType=cv2.BORDER_REFLECT)
    return out[pad : pad + img.shape[0]]


def noise_2d(rng: np.random.Generator, rows: int, cols: int, scale: int) -> np.ndarray:
    """(rows, cols) float32 smooth noise, unit std, feature size ``scale`` texels, periodic in rows.

    ``scale`` must be a power of two dividing ``rows``. White noise on a grid ``scale`` times
    coarser is blurred (wrapping in rows) and upsampled bicubically.
    """
    if rows % scale:
        raise ValueError(f"noise_2d: scale {scale} must divide rows {rows}")
    nr = rows // scale
    nc = -(-cols // scale) + 2
    g = rng.standard_normal((nr, nc)).astype(np.float32)
    if scale > 1:
        g = wrap_rows_blur(g, 0.7)
        g /= max(float(g.std()), 1e-6)
        p = 2
        g = cv2.copyMakeBorder(g, p, p, 0, 0, cv2.BORDER_WRAP)
        up = cv2.resize(g, (nc * scale, (nr + 2 * p) * scale), interpolation=cv2.INTER_CUBIC)
        out = up[p * scale : p * scale + rows, :cols]
    else:
        out = g[:, :cols]
    return np.ascontiguousarray(out, dtype=np.float32)


def smoothstep(e0: float, e1: float, x: np.ndarray) -> np.ndarray:
    t = np.clip((x - e0) / (e1 - e0), 0.0, 1.0)
    return t * t * (3 - 2 * t)


def blob_texture(size: int = 512, seed: int = 0) -> np.ndarray:
    """A smooth random RGB texture, (size, size, 3) uint8 in 40..220, with blobs at 3 scales (for
    analytic test scenes and benchmark rooms, outside the colon simulator's own streams)."""
    rng = np.random.default_rng(seed)
    tex = np.zeros((size, size, 3), np.float32)
    for cells in (4, 16, 64):
        noise = rng.random((cells, cells, 3)).astype(np.float32)
        tex += cv2.resize(noise, (size, size), interpolation=cv2.INTER_CUBIC) / 3
    tex = (tex - tex.min()) / (tex.max() - tex.min())
    return (40 + 180 * tex).astype(np.uint8)
