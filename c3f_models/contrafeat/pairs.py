"""Per-frame keypoints and per-pair ground truth from a ContraFeat batch (NumPy side).

The batch layout is :mod:`datamodules.base`'s; frame 0 of each sample is paired with each
later frame. SIFT runs on CPU on the uint8 version of the (inpainted) image, away from the
specular highlights; the ground truth comes from :func:`c3f_slam.matching.ground_truth_matches`.

Optionally (``DenseSettings.points > 0``, training only) a pair also carries dense
correspondences: pixels of frame i on a jittered grid, moved into frame j with the true depth
and poses (:func:`c3f_slam.matching.ground_truth.project_keypoints`), kept where visible. They
are not keypoints; they add supervision (and negatives) to the InfoNCE of the pair.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from c3f_core.errors import InputError
from c3f_slam.matching import Keypoints, Projection, detect_sift, ground_truth_matches
from c3f_slam.matching.ground_truth import DEPTH_TOLERANCE, PIXEL_RADIUS, project_keypoints


@dataclass
class Frame:
    """One frame of a batch as NumPy arrays (RGB uint8, depth metres, K pixels, pose camera-to-world)."""

    image: np.ndarray
    depth: np.ndarray
    K: np.ndarray
    pose: np.ndarray
    specular: np.ndarray | None = None


@dataclass(kw_only=True)
class PairData:
    """Keypoints of frames i and j and their ground-truth matches (M, 2)."""

    b: int
    i: int
    j: int
    kp_i: Keypoints
    kp_j: Keypoints
    gt: np.ndarray
    projection: Projection
    dense: tuple[np.ndarray, np.ndarray] | None = None  # (D, 2) pixels in i, (D, 2) their positions in j


@dataclass(frozen=True)
class KeypointSettings:
    """SIFT settings of ContraFeat (see :func:`c3f_slam.matching.detect_sift`); ContraFeat's ``keypoints``.

    Attributes:
        max_keypoints: SIFT keypoints kept per frame (strongest by response).
        contrast_threshold: OpenCV SIFT contrast threshold (lower = more keypoints).
        border: drop keypoints (and dense samples) this close to the border, pixels.
        mask_specular: no keypoints on specular highlights.
    """

    max_keypoints: int = 1024
    contrast_threshold: float = 0.04
    border: int = 2
    mask_specular: bool = True

    def __post_init__(self) -> None:
        if self.max_keypoints < 2:
            raise InputError(f"model.keypoints.max_keypoints must be >= 2, got {self.max_keypoints}")


@dataclass(frozen=True)
class GroundTruthSettings:
    """Ground-truth matching; ContraFeat's ``ground_truth``.

    Attributes:
        pixel_radius: ground-truth and correctness radius, pixels.
        depth_tolerance: relative depth agreement for visibility (occlusion test).
    """

    pixel_radius: float = PIXEL_RADIUS
    depth_tolerance: float = DEPTH_TOLERANCE

    def __post_init__(self) -> None:
        if self.pixel_radius <= 0 or self.depth_tolerance <= 0:
            raise InputError("model.ground_truth.pixel_radius and model.ground_truth.depth_tolerance must be positive")


@dataclass(frozen=True)
class DenseSettings:
    """Dense correspondences added to the training loss (0 points = off, the paper's loss).

    Attributes:
        points: pixels sampled per pair in frame i (before the visibility test).
        spacing: grid cell, pixels; one pixel per cell, jittered within the first half of the
            cell, so two samples are at least ``spacing / 2`` pixels apart (close pixels would be
            near-identical negatives).
        border: keep samples (in i and in j) this many pixels from the border.
    """

    points: int = 0
    spacing: int = 4
    border: int = 2


def dense_correspondences(
    fi: Frame, fj: Frame, settings: DenseSettings, gt_settings: GroundTruthSettings,
    rng: np.random.Generator, mask_specular: bool = True,
) -> tuple[np.ndarray, np.ndarray]:
    """(D, 2) pixels of frame i and (D, 2) their true positions in frame j (float64, D <= points).

    Samples lie on a jittered grid over i where i has depth (and, with ``mask_specular``, no
    highlight); they are projected into j with the true depth and poses and kept when
    visible there (inside, depth agrees within ``gt_settings.depth_tolerance``), at least
    ``border`` pixels inside, and not on a highlight of j.
    """
    h, w = fi.depth.shape
    s, half = max(int(settings.spacing), 1), max(int(settings.spacing) // 2, 1)
    gy, gx = np.mgrid[0:h:s, 0:w:s]
    xy = np.stack([gx.ravel(), gy.ravel()], axis=1) + rng.integers(0, half, size=(gx.size, 2))
    b = settings.border
    xy = xy[(xy[:, 0] >= b) & (xy[:, 0] < w - b) & (xy[:, 1] >= b) & (xy[:, 1] < h - b)]
    ok = fi.depth[xy[:, 1], xy[:, 0]] > 0
    if mask_specular and fi.specular is not None:
        ok &= ~fi.specular[xy[:, 1], xy[:, 0]]
    xy = xy[ok]
    if len(xy) > settings.points:
        xy = xy[rng.choice(len(xy), settings.points, replace=False)]
    xy = xy.astype(np.float64)
    proj = project_keypoints(xy, fi.depth, fj.depth, fi.K, T_wi=fi.pose, T_wj=fj.pose,
                             depth_tolerance=gt_settings.depth_tolerance)
    uv = proj.uv
    keep = proj.visible.copy()
    with np.errstate(invalid="ignore"):
        keep &= (uv[:, 0] >= b) & (uv[:, 0] <= w - 1 - b) & (uv[:, 1] >= b) & (uv[:, 1] <= h - 1 - b)
    if mask_specular and fj.specular is not None and keep.any():
        px = np.rint(uv[keep]).astype(np.int64)
        keep[np.flatnonzero(keep)[fj.specular[px[:, 1], px[:, 0]]]] = False
    return xy[keep], uv[keep]


def batch_frames(batch: dict) -> list[list[Frame]]:
    """Frames of every sample of a batch: ``frames[b][f]``."""
    img = (batch["image"].detach().float().clamp(0, 1) * 255.0 + 0.5).to(torch.uint8)
    img = img.permute(0, 1, 3, 4, 2).cpu().numpy()
    depth = batch["depth"].detach().float()[:, :, 0].cpu().numpy()
    K = batch["K"].detach().double().cpu().numpy()
    pose = batch["pose"].detach().double().cpu().numpy()
    spec = batch["specular"][:, :, 0].cpu().numpy().astype(bool) if "specular" in batch else None
    b_count, f_count = img.shape[:2]
    return [
        [Frame(img[b, f], depth[b, f], K[b], pose[b, f], None if spec is None else spec[b, f]) for f in range(f_count)]
        for b in range(b_count)
    ]


def frame_keypoints(frame: Frame, settings: KeypointSettings, descriptors: bool = False) -> Keypoints:
    """SIFT keypoints of one frame (optionally with SIFT descriptors for the baseline)."""
    mask = ~frame.specular if settings.mask_specular and frame.specular is not None else None
    return detect_sift(
        frame.image, settings.max_keypoints, mask=mask, descriptors=descriptors,
        contrast_threshold=settings.contrast_threshold, border=settings.border,
    )


def make_pairs(
    frames: list[list[Frame]], kp_settings: KeypointSettings, gt_settings: GroundTruthSettings,
    sift_descriptors: bool = False, dense: DenseSettings | None = None, rng: np.random.Generator | None = None,
) -> list[PairData]:
    """Pairs (frame 0, frame k) of every sample with keypoints and ground-truth matches.

    With ``dense`` (``points > 0``) each pair also gets :func:`dense_correspondences` drawn
    with ``rng``.
    """
    use_dense = dense is not None and dense.points > 0
    if use_dense and rng is None:
        rng = np.random.default_rng()
    out = []
    for b, sample in enumerate(frames):
        kps = [frame_keypoints(f, kp_settings, sift_descriptors) for f in sample]
        fi = sample[0]
        for j in range(1, len(sample)):
            fj = sample[j]
            gt, proj = ground_truth_matches(
                kps[0].xy, kps[j].xy, fi.depth, fj.depth, K=fi.K, T_wi=fi.pose, T_wj=fj.pose,
                pixel_radius=gt_settings.pixel_radius, depth_tolerance=gt_settings.depth_tolerance,
                return_projection=True,
            )
            extra = (
                dense_correspondences(fi, fj, dense, gt_settings, rng, kp_settings.mask_specular) if use_dense else None
            )
            out.append(PairData(b=b, i=0, j=j, kp_i=kps[0], kp_j=kps[j], gt=gt, projection=proj, dense=extra))
    return out
