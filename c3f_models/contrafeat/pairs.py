"""Per-frame keypoints and per-pair ground truth from a ContraFeat batch (NumPy side).

The batch layout is :mod:`datamodules.base`'s; frame 0 of each sample is paired with each
later frame. SIFT runs on CPU on the uint8 version of the (inpainted) image, away from the
specular highlights; the ground truth comes from :func:`c3f_slam.matching.ground_truth_matches`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from c3f_slam.matching import Keypoints, Projection, detect_sift, ground_truth_matches


@dataclass
class Frame:
    """One frame of a batch as NumPy arrays (RGB uint8, depth metres, K pixels, pose camera-to-world)."""

    image: np.ndarray
    depth: np.ndarray
    K: np.ndarray
    pose: np.ndarray
    specular: np.ndarray | None = None


@dataclass
class PairData:
    """Keypoints of frames i and j and their ground-truth matches (M, 2)."""

    b: int
    i: int
    j: int
    kp_i: Keypoints
    kp_j: Keypoints
    gt: np.ndarray
    projection: Projection


@dataclass(frozen=True)
class KeypointSettings:
    """SIFT settings of ContraFeat (see :func:`c3f_slam.matching.detect_sift`)."""

    max_keypoints: int = 1024
    contrast_threshold: float = 0.04
    border: int = 2
    mask_specular: bool = True


@dataclass(frozen=True)
class GroundTruthSettings:
    """Ground-truth matching (pixels, relative depth tolerance)."""

    pixel_radius: float = 2.0
    depth_tolerance: float = 0.05


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
    sift_descriptors: bool = False,
) -> list[PairData]:
    """Pairs (frame 0, frame k) of every sample with keypoints and ground-truth matches."""
    out = []
    for b, sample in enumerate(frames):
        kps = [frame_keypoints(f, kp_settings, sift_descriptors) for f in sample]
        fi = sample[0]
        for j in range(1, len(sample)):
            fj = sample[j]
            gt, proj = ground_truth_matches(
                kps[0].xy, kps[j].xy, fi.depth, fj.depth, fi.K, fi.pose, fj.pose,
                pixel_radius=gt_settings.pixel_radius, depth_tolerance=gt_settings.depth_tolerance,
                return_projection=True,
            )
            out.append(PairData(b, 0, j, kps[0], kps[j], gt, proj))
    return out
