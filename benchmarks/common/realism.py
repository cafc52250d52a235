"""How close a set of frames looks to a set of real frames, without ground truth.

The question is whether a network trained on simulated frames meets, on real video, the same
low-level statistics it was trained on: colour, sharpness and texture, noise. The statistic
(``total``) is the mean of four distances between the two sets, each in [0, 1] for practical
purposes and 0 for identical sets; lower = closer:

- ``colour``: per channel, the 1-D Wasserstein (earth mover's) distance between the histograms
  of the R, G and B grey levels inside the tissue, over 255; the mean of the three. Wasserstein,
  unlike histogram intersection, grows with how far the colours moved, not only whether they did.
- ``gradient``: the Wasserstein distance between the histograms of log(1 + |Sobel gradient|) of
  the luminance (grey levels per pixel, 3x3 Sobel / 8) inside the tissue, over log(256): the
  sharpness and texture contrast (blur moves it down, noise and hard edges up).
- ``noise``: the Wasserstein distance between the per-frame noise levels, log(1 + sigma) over
  log(256), sigma estimated by Immerkaer's Laplacian-difference filter (Immerkaer, CVIU 1996:
  sigma = sqrt(pi / 2) / 6 x mean |I * M|, M the 3x3 difference of two Laplacians, grey levels).
  Fine texture also counts; it is the level of the finest detail.
- ``nearest``: per simulated frame, its descriptor distance to the nearest real frame (the mean
  over the :data:`NEAREST_K` nearest, 1 by default, so identical sets give 0), averaged over the
  simulated frames. The descriptor (:func:`descriptor`) is
  four histograms of the frame's tissue (hue 12 / saturation 8 / value 8 bins, and 8 bins of
  log(1 + |gradient|)), each summing to 1; the distance between two frames
  (:func:`descriptor_distances`) is the mean over the four of the Hellinger distance
  sqrt(1 - sum sqrt(p q)), in [0, 1].

Why per frame, and not the Frechet distance between Gaussians fitted to the descriptors (as FID
does with network features; still reported as ``frechet``, outside the total): the Frechet
distance also compares the sets' spreads, trace(C_a + C_b - 2 (C_a C_b)^1/2), so against a real
set of one scene (the C3VD phantom clip: one colon, one light, one look) every extra look of a
varied simulated set adds to it, and a set made as uniform as that scene wins. Training data must
be varied (real patients differ from this phantom: pinker or redder mucosa, wetter, more
vessels). A per-frame distance to the nearest real frames asks instead whether each simulated
frame looks like some real frame; a varied set is not penalised for its variety, only for frames
far from all real ones (it does not reward variety either). Mahalanobis distances to the real
set's mean and covariance were not taken: the covariance of one scene is nearly singular, so they
would again punish any look outside that scene's narrow spread. The pooled histogram terms
(colour, gradient, noise) are 1-D Wasserstein distances of a pooled set, which are convex in the
mixture, so they do not penalise variety more than the per-frame average of the same distance.

All frames are first resized (area filter) so that their smaller side is ``size`` pixels: the
sets may come from different resolutions, and gradients and noise depend on the scale. Pixels
outside the tissue (a scope's black border) are left out via masks (True = tissue), e.g. from
:func:`static_border`. Pooled histograms and Gaussian statistics do not depend on the frames'
order.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import cv2
import numpy as np
from scipy import linalg

__all__ = ["DIAGNOSTICS", "NEAREST_K", "TERMS", "descriptor", "descriptor_distances", "nearest_distances",
           "noise_sigma", "realism", "realism_distance", "static_border"]

TERMS = ("colour", "gradient", "noise", "nearest")  #: the terms of ``total``
DIAGNOSTICS = ("frechet",)  #: reported beside them, not in ``total`` (module docstring)
NEAREST_K = 1  #: real frames a simulated frame is compared with (its nearest ones; 1: identical sets give 0)
#: the descriptor's histograms: (first, last + 1) of each
GROUPS = ((0, 12), (12, 20), (20, 28), (28, 36))
LOG256 = math.log(256.0)
_IMMERKAER = np.array([[1, -2, 1], [-2, 4, -2], [1, -2, 1]], np.float32)


def static_border(frames: Sequence[np.ndarray], level: int = 30, erode_px: int = 2) -> np.ndarray:
    """(H, W) bool tissue mask of a recording with a fixed black border: False where a pixel's
    brightest channel stays below ``level`` (grey levels) in every frame and the region touches the
    frame edge, shrunk by ``erode_px`` pixels (the border's soft edge)."""
    peak = np.max(np.stack([f.max(axis=2) for f in frames]), axis=0)
    dark = (peak < level).astype(np.uint8)
    n, labels = cv2.connectedComponents(dark, connectivity=4)
    edge = set(np.unique(np.concatenate([labels[0], labels[-1], labels[:, 0], labels[:, -1]])).tolist())
    border = np.isin(labels, [k for k in edge if k != 0]) & (dark > 0)
    tissue = (~border).astype(np.uint8)
    if erode_px > 0:
        tissue = cv2.erode(tissue, np.ones((2 * erode_px + 1, 2 * erode_px + 1), np.uint8))
    return tissue > 0


def _prepare(frames: Sequence[np.ndarray], masks: Sequence[np.ndarray] | np.ndarray | None,
             size: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """Frames resized to smaller side ``size`` with their masks (nearest, eroded by 1 px)."""
    if len(frames) == 0:
        raise ValueError("realism: an empty set of frames")
    out = []
    for k, f in enumerate(frames):
        if f.ndim != 3 or f.shape[2] != 3 or f.dtype != np.uint8:
            raise ValueError(f"realism: frame {k} must be (H, W, 3) uint8, got {f.shape} {f.dtype}")
        h, w = f.shape[:2]
        s = size / min(h, w)
        dst = (max(1, round(w * s)), max(1, round(h * s)))
        img = cv2.resize(f, dst, interpolation=cv2.INTER_AREA) if dst != (w, h) else f
        if masks is None:
            m = np.ones(img.shape[:2], bool)
        else:
            m0 = masks if isinstance(masks, np.ndarray) else masks[k]
            m = cv2.resize(m0.astype(np.uint8), dst, interpolation=cv2.INTER_NEAREST)
            m = cv2.erode(m, np.ones((3, 3), np.uint8)) > 0
        out.append((img, m))
    return out


def _gradient(grey: np.ndarray) -> np.ndarray:
    """|Sobel gradient| of a float32 image in grey levels per pixel."""
    gx = cv2.Sobel(grey, cv2.CV_32F, 1, 0, ksize=3) / 8.0
    gy = cv2.Sobel(grey, cv2.CV_32F, 0, 1, ksize=3) / 8.0
    return np.sqrt(gx * gx + gy * gy)


def noise_sigma(rgb: np.ndarray, mask: np.ndarray | None = None) -> float:
    """Immerkaer's noise std estimate of the luminance, grey levels, over the pixels of ``mask``
    (None: all; pixels next to the mask's edge are left out)."""
    grey = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY).astype(np.float32)
    r = np.abs(cv2.filter2D(grey, cv2.CV_32F, _IMMERKAER, borderType=cv2.BORDER_REFLECT_101))
    keep = np.ones(grey.shape, bool) if mask is None else cv2.erode(mask.astype(np.uint8), np.ones((3, 3))) > 0
    keep[[0, -1], :] = False
    keep[:, [0, -1]] = False
    if not keep.any():
        return 0.0
    return float(math.sqrt(math.pi / 2.0) / 6.0 * r[keep].mean())


def descriptor(rgb: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """(36,) float64 descriptor of one frame's tissue: hue (12 bins), saturation (8) and value (8)
    histograms and a histogram of log(1 + |gradient|) (8 bins over [0, log 256]), each summing to 1."""
    hsv = cv2.cvtColor(rgb, cv2.COLOR_RGB2HSV_FULL)[mask]
    parts = [np.histogram(hsv[:, 0], 12, (0, 256))[0], np.histogram(hsv[:, 1], 8, (0, 256))[0],
             np.histogram(hsv[:, 2], 8, (0, 256))[0]]
    g = np.log1p(_gradient(cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY).astype(np.float32))[mask])
    parts.append(np.histogram(g, 8, (0.0, LOG256))[0])
    return np.concatenate([p / max(p.sum(), 1) for p in parts]).astype(np.float64)


def _wasserstein(a: np.ndarray, b: np.ndarray, bins: int, lo: float, hi: float) -> float:
    """1-D Wasserstein distance between the histograms of samples ``a`` and ``b`` over
    [``lo``, ``hi``], in units of that range (0..1)."""
    ha = np.histogram(a, bins, (lo, hi))[0].astype(np.float64)
    hb = np.histogram(b, bins, (lo, hi))[0].astype(np.float64)
    ca, cb = np.cumsum(ha / max(ha.sum(), 1)), np.cumsum(hb / max(hb.sum(), 1))
    return float(np.abs(ca - cb).sum() / bins)


def _frechet(da: np.ndarray, db: np.ndarray) -> float:
    """sqrt of the Frechet distance between Gaussians fitted to the rows of ``da`` and ``db``."""
    mu_a, mu_b = da.mean(0), db.mean(0)
    ca = np.cov(da, rowvar=False) if len(da) > 1 else np.zeros((da.shape[1],) * 2)
    cb = np.cov(db, rowvar=False) if len(db) > 1 else np.zeros((db.shape[1],) * 2)
    ridge = 1e-8 * np.eye(len(mu_a))  # few frames: singular covariances
    ca, cb = ca + ridge, cb + ridge
    root = linalg.sqrtm(ca @ cb)
    root = np.real(root) if np.iscomplexobj(root) else root
    fd = float(((mu_a - mu_b) ** 2).sum() + np.trace(ca + cb - 2.0 * root))
    return math.sqrt(max(fd, 0.0))


def descriptor_distances(da: np.ndarray, db: np.ndarray) -> np.ndarray:
    """(len(da), len(db)) distances between the rows of two descriptor arrays (:func:`descriptor`):
    the mean over the four histograms of the Hellinger distance sqrt(1 - sum sqrt(p q)), 0..1."""
    sa, sb = np.sqrt(np.clip(da, 0.0, None)), np.sqrt(np.clip(db, 0.0, None))
    out = np.zeros((len(da), len(db)))
    for lo, hi in GROUPS:
        bc = sa[:, lo:hi] @ sb[:, lo:hi].T
        out += np.sqrt(np.clip(1.0 - bc, 0.0, 1.0))
    return out / len(GROUPS)


def _nearest(da: np.ndarray, db: np.ndarray, k: int = NEAREST_K) -> np.ndarray:
    """Per row of ``da``: the mean of its ``k`` smallest distances to the rows of ``db``."""
    d = descriptor_distances(da, db)
    k = max(1, min(k, d.shape[1]))
    return np.sort(d, axis=1)[:, :k].mean(axis=1)


def _set_stats(prepared: list[tuple[np.ndarray, np.ndarray]]) -> dict[str, np.ndarray]:
    rgb = np.concatenate([img[m] for img, m in prepared])
    grads, sig, desc = [], [], []
    for img, m in prepared:
        grey = cv2.cvtColor(img, cv2.COLOR_RGB2GRAY).astype(np.float32)
        inner = cv2.erode(m.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
        grads.append(np.log1p(_gradient(grey)[inner]))
        sig.append(math.log1p(noise_sigma(img, m)))
        desc.append(descriptor(img, m))
    return {"rgb": rgb, "grad": np.concatenate(grads), "noise": np.array(sig), "desc": np.stack(desc)}


def realism(frames: Sequence[np.ndarray], real: Sequence[np.ndarray],
            masks: Sequence[np.ndarray] | np.ndarray | None = None,
            real_masks: Sequence[np.ndarray] | np.ndarray | None = None, size: int = 128) -> dict[str, float]:
    """The four distances of the module docstring between ``frames`` and ``real`` (lists of
    (H, W, 3) uint8 RGB frames, any sizes), ``total``, their mean, and the diagnostic ``frechet``
    (not in the total). ``masks`` / ``real_masks``:
    one (H, W) bool tissue mask for all frames of a set or one per frame (None: every pixel)."""
    a, b = _set_stats(_prepare(frames, masks, size)), _set_stats(_prepare(real, real_masks, size))
    out = {"colour": float(np.mean([_wasserstein(a["rgb"][:, c], b["rgb"][:, c], 256, 0, 256) for c in range(3)])),
           "gradient": _wasserstein(a["grad"], b["grad"], 256, 0.0, LOG256),
           "noise": _wasserstein(a["noise"], b["noise"], 256, 0.0, LOG256),
           "nearest": float(_nearest(a["desc"], b["desc"]).mean()),
           "frechet": _frechet(a["desc"], b["desc"])}
    out["total"] = float(np.mean([out[t] for t in TERMS]))
    return out


def nearest_distances(frames: Sequence[np.ndarray], real: Sequence[np.ndarray],
                      masks: Sequence[np.ndarray] | np.ndarray | None = None,
                      real_masks: Sequence[np.ndarray] | np.ndarray | None = None, size: int = 128,
                      k: int = NEAREST_K) -> np.ndarray:
    """(len(frames),) per-frame distances of ``nearest`` (module docstring): each frame's mean
    descriptor distance to its ``k`` nearest ``real`` frames, 0..1; masks and size as :func:`realism`."""
    da = np.stack([descriptor(img, m) for img, m in _prepare(frames, masks, size)])
    db = np.stack([descriptor(img, m) for img, m in _prepare(real, real_masks, size)])
    return _nearest(da, db, k)


def realism_distance(frames: Sequence[np.ndarray], real: Sequence[np.ndarray], **kwargs) -> float:
    """``realism(frames, real, **kwargs)["total"]``: lower = closer to the real frames."""
    return realism(frames, real, **kwargs)["total"]
