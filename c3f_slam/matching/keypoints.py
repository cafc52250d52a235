"""SIFT keypoints (OpenCV) with a cap on the number per frame.

Keypoint coordinates are OpenCV's: (u, v) pixels, integer values at pixel centres.
SIFT reports one keypoint per dominant orientation, so a location can appear several
times; :func:`detect_sift` keeps only the strongest keypoint per location (a dense
descriptor map gives identical descriptors at identical pixels, which would make
contrastive negatives equal to their positives).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from c3f_core.errors import InputError


@dataclass(frozen=True)
class Keypoints:
    """Keypoints of one frame.

    Attributes:
        xy: (N, 2) float64 pixel coordinates (u, v).
        response: (N,) float32 detector response (strongest first).
        size: (N,) float32 SIFT scale (diameter, pixels).
        descriptors: (N, 128) float32 SIFT descriptors, or None if not computed.
    """

    xy: np.ndarray
    response: np.ndarray
    size: np.ndarray
    descriptors: np.ndarray | None = None

    def __len__(self) -> int:
        return int(self.xy.shape[0])

    @classmethod
    def empty(cls, with_descriptors: bool = True) -> Keypoints:
        return cls(
            np.zeros((0, 2), np.float64),
            np.zeros(0, np.float32),
            np.zeros(0, np.float32),
            np.zeros((0, 128), np.float32) if with_descriptors else None,
        )


def to_gray_uint8(image: np.ndarray) -> np.ndarray:
    """(H, W) or (H, W, 3) RGB image, uint8 or float in [0, 1], to (H, W) uint8 grey."""
    img = np.asarray(image)
    if img.ndim == 3 and img.shape[2] == 1:
        img = img[..., 0]
    if img.ndim not in (2, 3) or (img.ndim == 3 and img.shape[2] != 3):
        raise InputError(f"image must be (H, W) or (H, W, 3), got shape {img.shape}")
    if img.dtype != np.uint8:
        if not np.issubdtype(img.dtype, np.floating):
            raise InputError(f"image must be uint8 or float in [0, 1], got {img.dtype}")
        img = np.clip(np.nan_to_num(img) * 255.0 + 0.5, 0, 255).astype(np.uint8)
    if img.ndim == 3:
        img = cv2.cvtColor(np.ascontiguousarray(img), cv2.COLOR_RGB2GRAY)
    return np.ascontiguousarray(img)


def _strongest_per_location(
    xy: np.ndarray, response: np.ndarray, width: int, height: int, border: int, max_keypoints: int | None
) -> np.ndarray:
    """Indices of the detections to keep, strongest ``response`` first: one per location
    (``xy`` in pixels, rounded to 0.01 px), none closer than ``border`` pixels to the edge of a
    ``width`` x ``height`` image, at most ``max_keypoints`` (None = no cap)."""
    order = np.argsort(-response, kind="stable")
    _, first = np.unique(np.round(xy[order] * 100).astype(np.int64), axis=0, return_index=True)
    keep = order[np.sort(first)]
    if border > 0:
        x, y = xy[keep, 0], xy[keep, 1]
        keep = keep[(x >= border) & (y >= border) & (x <= width - 1 - border) & (y <= height - 1 - border)]
    if max_keypoints is not None:
        keep = keep[: int(max_keypoints)]
    return keep


def detect_sift(
    image: np.ndarray,
    max_keypoints: int | None,
    mask: np.ndarray | None = None,
    descriptors: bool = True,
    contrast_threshold: float = 0.04,
    edge_threshold: float = 10.0,
    sigma: float = 1.6,
    n_octave_layers: int = 3,
    border: int = 0,
) -> Keypoints:
    """Detect SIFT keypoints, one per location, the ``max_keypoints`` strongest by response.

    Args:
        image: (H, W[, 3]) RGB, uint8 or float in [0, 1].
        max_keypoints: cap per frame (None = no cap; the caller's setting, e.g. ``frontend.max_keypoints``).
        mask: optional (H, W) bool; keypoints only where True (e.g. not specular).
        descriptors: also compute the 128-d SIFT descriptors (the SIFT baseline).
        contrast_threshold, edge_threshold, sigma, n_octave_layers: OpenCV SIFT settings.
        border: drop keypoints closer than this many pixels to the image border.
    """
    gray = to_gray_uint8(image)
    h, w = gray.shape
    cv_mask = None
    if mask is not None:
        mask = np.asarray(mask)
        if mask.shape != (h, w):
            raise InputError(f"keypoint mask shape {mask.shape} does not match the image {(h, w)}")
        cv_mask = mask.astype(np.uint8) * 255
    sift = cv2.SIFT_create(
        nfeatures=0,
        nOctaveLayers=n_octave_layers,
        contrastThreshold=contrast_threshold,
        edgeThreshold=edge_threshold,
        sigma=sigma,
    )
    kps = sift.detect(gray, cv_mask)
    if not kps:
        return Keypoints.empty(descriptors)
    xy = np.array([k.pt for k in kps], np.float64)
    resp = np.array([k.response for k in kps], np.float32)
    kps = [kps[i] for i in _strongest_per_location(xy, resp, w, h, border, max_keypoints)]
    desc = None
    if descriptors:
        kps, desc = sift.compute(gray, kps)
        desc = np.zeros((0, 128), np.float32) if desc is None else desc.astype(np.float32)
    return Keypoints(
        xy=np.array([k.pt for k in kps], np.float64).reshape(-1, 2),
        response=np.array([k.response for k in kps], np.float32),
        size=np.array([k.size for k in kps], np.float32),
        descriptors=desc,
    )
