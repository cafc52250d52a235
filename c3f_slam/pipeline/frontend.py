"""Per-frame frontend: keypoints, descriptors, 3D points; and pairwise frame matching.

Conventions (as :mod:`c3f_slam.matching`): keypoints (u, v) pixels; 3D points in the
camera frame, metres, NaN rows where there is no depth; ``T_ij`` maps frame-j points into
frame i (p_i = T_ij p_j).

Seams: a :class:`DescriptorProvider` turns a frame and its keypoints into (N, D) descriptors
(:class:`SiftDescriptors`, or :class:`ContraFeatDescriptors` from a ContraFeat ONNX export);
a :class:`DepthProvider` gives the depth of a frame in metres (:class:`FileDepth` from the
sequence's depth/ files, or :class:`ModelDepth` from a DepthNet ONNX export). The model
providers are bound to the stream's camera, whose intrinsics the frames already match.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import cv2
import numpy as np

from c3f_core.errors import InputError
from c3f_slam.camera.intrinsics import PinholeCamera
from c3f_slam.config import FrontendConfig, SlamConfig
from c3f_slam.frames.preprocess import SPECULAR_DILATION_PX, on_grid, specular_mask
from c3f_slam.frames.stream import StreamFrame
from c3f_slam.geometry import invert_pose, project, transform_points
from c3f_slam.matching import (
    Keypoints,
    MatchFilterConfig,
    detect_sift,
    filter_matches,
    lift_keypoints,
    mutual_nearest_neighbours,
    to_gray_uint8,
)
from c3f_slam.matching.reprojection import refine_by_reprojection
from c3f_slam.models import DepthModel, DescriptorModel, NetworkView


class DescriptorProvider(Protocol):
    """Descriptors of keypoints: ``describe(rgb, keypoints) -> (N, D)``.

    ``metric`` is how :func:`mutual_nearest_neighbours` compares them (``l2`` or
    ``cosine``); ``storage_dtype`` is how keyframes store them (uint8 for SIFT, float16 for
    unit-norm learned descriptors). ``needs_sift_descriptors``: the detector should compute
    SIFT descriptors alongside (saves a second pass for the SIFT provider).
    """

    name: str
    metric: str
    storage_dtype: np.dtype
    needs_sift_descriptors: bool

    def describe(self, rgb: np.ndarray, keypoints: Keypoints) -> np.ndarray: ...


class SiftDescriptors:
    """128-d SIFT descriptors (the paper's SIFT baseline); stored as uint8 (OpenCV values are
    integers 0..255 in float32)."""

    name = "sift"
    metric = "l2"
    storage_dtype = np.dtype(np.uint8)
    needs_sift_descriptors = True

    def describe(self, rgb: np.ndarray, keypoints: Keypoints) -> np.ndarray:
        if keypoints.descriptors is not None:
            return keypoints.descriptors
        if len(keypoints) == 0:
            return np.zeros((0, 128), np.float32)
        kps = [cv2.KeyPoint(float(x), float(y), float(s)) for (x, y), s in zip(keypoints.xy, keypoints.size)]
        _, desc = cv2.SIFT_create().compute(to_gray_uint8(rgb), kps)
        return np.zeros((0, 128), np.float32) if desc is None else desc.astype(np.float32)


class ContraFeatDescriptors:
    """ContraFeat descriptors (ONNX) sampled at the SIFT keypoints; unit norm, compared by
    cosine similarity, stored as float16."""

    name = "contrafeat"
    metric = "cosine"
    storage_dtype = np.dtype(np.float16)
    needs_sift_descriptors = False

    def __init__(self, model: DescriptorModel, camera: PinholeCamera, tissue: np.ndarray | None = None) -> None:
        """``tissue``: (H, W) bool tissue area of the frames (None: the whole frame); the network
        sees the border filled from the tissue (:func:`c3f_slam.frames.preprocess.prepare_network_input`)."""
        self.model = model
        self.camera = camera
        self.tissue = tissue
        model.view(camera)  # the model's crop must fit these frames (InputError now, not mid-run)

    def describe(self, rgb: np.ndarray, keypoints: Keypoints) -> np.ndarray:
        return self.model.describe(rgb, self.camera, keypoints.xy, self.tissue)


class DepthProvider(Protocol):
    """Depth of a streamed frame, (H, W) float32 metres, 0 = none."""

    name: str

    def depth(self, frame: StreamFrame) -> np.ndarray: ...


class FileDepth:
    """RGB-D mode: the depth read from the sequence's depth/ files."""

    name = "files"

    def __init__(self, tissue: np.ndarray | None = None) -> None:
        """``tissue``: (H, W) bool tissue area of the frames; depth outside it is 0 (None: the whole frame)."""
        self.tissue = tissue

    def depth(self, frame: StreamFrame) -> np.ndarray:
        if frame.depth is None:
            raise InputError(f"frame {frame.index}: --depth-source files but the sequence has no depth/ folder")
        return frame.depth if self.tissue is None else np.where(self.tissue, frame.depth, np.float32(0.0))


@dataclass(frozen=True)
class DepthPrediction:
    """A DepthNet prediction of one frame: ``network`` (h, w) float32 metres on the network
    grid described by ``view`` (``view.camera``: its intrinsics) and ``frame`` (H, W) float32
    metres resized back onto the frame (0 outside the crop box)."""

    index: int
    network: np.ndarray
    frame: np.ndarray
    view: NetworkView


class ModelDepth:
    """Depth from a DepthNet ONNX export (metres, the frame's pixel grid).

    ``scale`` multiplies the network's depth (network and frame grids alike). A
    self-supervised DepthNet knows depth only up to a scale, and the runtime's thresholds are
    in metres. None (default) takes the factor the exporter measured on the training data
    (``DepthModel.metric_scale``), else 1; ``scale_source`` says which ("option", "model
    metadata", "none"). ``benchmarks/studies/depth_motion.py`` measures the factor on any sequence
    with true depth. ``tissue``: (H, W) bool tissue area of the frames (None: the whole frame):
    the network sees the border filled from the tissue, and depth outside it is 0 on both grids.
    :meth:`predict` gives both grids (perception keeps the network grid for fusion), so the
    network runs once per frame; nothing is cached, so perception threads may call it for
    several frames at once.
    """

    name = "model"

    def __init__(self, model: DepthModel, camera: PinholeCamera, scale: float | None = None,
                 tissue: np.ndarray | None = None) -> None:
        if scale is not None and not (np.isfinite(scale) and scale > 0):
            raise InputError(f"--depth-scale must be a positive number, got {scale}")
        self.model = model
        self.camera = camera
        if scale is not None:
            self.scale, self.scale_source = float(scale), "option"
        elif model.metric_scale is not None:
            self.scale, self.scale_source = model.metric_scale, "model metadata"
        else:
            self.scale, self.scale_source = 1.0, "none"
        self.view = model.view(camera)  # InputError now when the model's crop does not fit
        self.tissue = tissue
        self.network_tissue = None if tissue is None else on_grid(tissue, self.view.box, self.view.size)

    def predict(self, frame: StreamFrame) -> DepthPrediction:
        net, view = self.model.predict_network(frame.rgb, self.camera, self.tissue)
        if self.scale != 1.0:
            net = net * np.float32(self.scale)
        if self.tissue is None:
            return DepthPrediction(frame.index, net, view.network_to_frame(net, self.model.upsample), view)
        net = np.where(self.network_tissue, net, np.float32(0.0))
        full = view.network_to_frame(net, self.model.upsample)
        return DepthPrediction(frame.index, net, np.where(self.tissue, full, np.float32(0.0)), view)

    def depth(self, frame: StreamFrame) -> np.ndarray:
        return self.predict(frame).frame


@dataclass(slots=True)
class FrameFeatures:
    """What the runtime keeps of a frame (never the image): keypoints (N, 2) float32 px,
    descriptors (N, D) in the provider's storage dtype, points (N, 3) float32 camera-frame
    metres (NaN = no depth). The length is the number of descriptors: stored keyframes keep
    no pixel keypoints (``xy`` (0, 2); matching reads descriptors and points only)."""

    index: int
    timestamp: float
    xy: np.ndarray
    descriptors: np.ndarray
    points: np.ndarray

    def __len__(self) -> int:
        return len(self.descriptors)

    def subset(self, n: int) -> FrameFeatures:
        """The first ``n`` (strongest) keypoints with depth."""
        ok = np.flatnonzero(np.isfinite(self.points).all(axis=1))[:n]
        return FrameFeatures(self.index, self.timestamp, self.xy[ok], self.descriptors[ok], self.points[ok])

    @property
    def nbytes(self) -> int:
        return int(self.xy.nbytes + self.descriptors.nbytes + self.points.nbytes)


class Frontend:
    """Keypoints inside the tissue area and outside speculars, descriptors and 3D points of one frame."""

    def __init__(self, K: np.ndarray, descriptors: DescriptorProvider | None = None,
                 cfg: FrontendConfig | None = None, tissue: np.ndarray | None = None) -> None:
        """``K``: 3x3 intrinsics of the frames (px); ``descriptors`` default SIFT; ``tissue``:
        (H, W) bool tissue area of the frames, where keypoints may lie (None: the whole frame)."""
        self.K = np.asarray(K, dtype=np.float64)
        self.tissue = tissue
        self.provider = descriptors or SiftDescriptors()
        self.cfg = cfg or FrontendConfig()

    def dilation(self, rgb: np.ndarray) -> int:
        """Specular-mask dilation (px) for this frame size (``FrontendConfig.specular_dilation_px``)."""
        if self.cfg.specular_dilation_px is not None:
            return int(self.cfg.specular_dilation_px)
        px = int(round(SPECULAR_DILATION_PX * min(rgb.shape[:2]) / 512.0))
        return max(3, px | 1)

    def keypoints(self, rgb: np.ndarray) -> Keypoints:
        mask = ~specular_mask(rgb, dilation_px=self.dilation(rgb)) if self.cfg.mask_specular else None
        if self.tissue is not None:
            mask = self.tissue if mask is None else mask & self.tissue
        return detect_sift(
            rgb, self.cfg.max_keypoints, mask=mask, descriptors=self.provider.needs_sift_descriptors,
            contrast_threshold=self.cfg.sift_contrast_threshold,
        )

    def describe(self, frame: StreamFrame, kp: Keypoints, depth: np.ndarray) -> FrameFeatures:
        desc = np.asarray(self.provider.describe(frame.rgb, kp))
        if len(desc) != len(kp):
            raise ValueError(f"descriptor provider {self.provider.name!r} returned {len(desc)} rows "
                             f"for {len(kp)} keypoints")
        pts = lift_keypoints(kp.xy, depth, self.K).astype(np.float32)
        dt = self.provider.storage_dtype
        if dt == np.uint8:
            desc = np.clip(np.rint(desc), 0, 255).astype(np.uint8)
        else:
            desc = desc.astype(dt)
        return FrameFeatures(frame.index, frame.timestamp, kp.xy.astype(np.float32), desc, pts)


@dataclass(frozen=True)
class PairMatch:
    """An accepted match of frames i and j: ``T_ij`` (p_i = T_ij p_j), the inlier 3D points of
    frame j (its camera frame, metres; for the information matrix) and their count."""

    T_ij: np.ndarray
    points_j: np.ndarray
    n: int


@dataclass(frozen=True)
class MatchAttempt:
    """Everything :func:`explain_match` found for frames i and j: ``candidates`` mutual
    nearest-neighbour descriptor matches, ``filtered`` the filter's survivors (also when it
    rejected the set), ``match`` the accepted match or None, and ``reason`` why not ("" when
    accepted)."""

    candidates: int
    filtered: int
    match: PairMatch | None
    reason: str


def projection_mask(fi: FrameFeatures, fj: FrameFeatures, T_ij: np.ndarray, K: np.ndarray,
                    radius_px: float) -> np.ndarray:
    """(N_i, N_j) bool: frame i's keypoints (their 3D points) moved into frame j by the motion
    prior ``T_ij`` (p_i = T_ij p_j) land within ``radius_px`` of frame j's keypoint (guided
    matching, as ORB-SLAM's search by projection); keypoints without depth match nothing."""
    uv, z = project(transform_points(invert_pose(np.asarray(T_ij, dtype=np.float64)), fi.points), K)
    uv = np.where((np.isfinite(uv).all(axis=1) & (z > 1e-6))[:, None], uv, np.inf)
    d2 = np.square(uv[:, None, :] - fj.xy.astype(np.float64)[None, :, :]).sum(axis=2)
    return (d2 <= radius_px**2) & np.isfinite(fj.points).all(axis=1)[None, :]


def explain_match(
    fi: FrameFeatures,
    fj: FrameFeatures,
    cfg: MatchFilterConfig,
    metric: str = "l2",
    ratio: float | None = 0.9,
    allowed: np.ndarray | None = None,
    K: np.ndarray | None = None,
) -> MatchAttempt:
    """Mutual NN (+ ratio test; among the ``allowed`` pairs only, if given:
    :func:`projection_mask`) then :func:`filter_matches`, with the outcome of each step
    (the runtime's pair matching; :func:`match_frames` returns its result only). With the
    intrinsics ``K`` and ``cfg.reprojection_refit`` the accepted transform is refitted by
    :func:`refine_by_reprojection`."""
    if len(fi) < cfg.min_matches or len(fj) < cfg.min_matches:
        return MatchAttempt(0, 0, None, f"too few keypoints ({len(fi)}, {len(fj)} < {cfg.min_matches})")
    m, dist = mutual_nearest_neighbours(
        fi.descriptors.astype(np.float32), fj.descriptors.astype(np.float32), metric, ratio=ratio, allowed=allowed
    )
    if len(m) < cfg.min_matches:
        return MatchAttempt(len(m), 0, None, f"too few descriptor matches ({len(m)} < {cfg.min_matches})")
    pi, pj = fi.points[m[:, 0]].astype(np.float64), fj.points[m[:, 1]].astype(np.float64)
    res = filter_matches(pi, pj, cfg, priority=dist)
    if not res.accepted:
        return MatchAttempt(len(m), len(res.inlier_indices), None, res.reason)
    kept = res.kept
    T_ij = res.T_ij
    if K is not None and cfg.reprojection_refit:
        T_ij = refine_by_reprojection(T_ij, pi[kept], pj[kept], K, cfg.reprojection_huber_px)
    return MatchAttempt(len(m), len(kept), PairMatch(T_ij, pj[kept], len(kept)), "")


def match_frames(
    fi: FrameFeatures,
    fj: FrameFeatures,
    cfg: MatchFilterConfig,
    metric: str = "l2",
    ratio: float | None = 0.9,
    K: np.ndarray | None = None,
) -> tuple[PairMatch | None, int]:
    """Mutual NN + :func:`filter_matches` (+ the reprojection refit, given ``K``); returns
    (match or None, number of inliers)."""
    a = explain_match(fi, fj, cfg, metric, ratio, K=K)
    return a.match, (a.match.n if a.match is not None else 0)


#: matches two frames: (match or None, number of inliers)
Matcher = Callable[[FrameFeatures, FrameFeatures], "tuple[PairMatch | None, int]"]


def frame_matcher(cfg: SlamConfig, metric: str = "l2", K: np.ndarray | None = None) -> Matcher:
    """:func:`match_frames` with the run's match filter and ratio test (and the frames'
    intrinsics ``K``, for the reprojection refit)."""
    K = None if K is None else np.asarray(K, dtype=np.float64)
    return lambda a, b: match_frames(a, b, cfg.match_filter, metric, cfg.frontend.ratio, K)


#: matches frames i and j near where a motion prior T_ij (p_i = T_ij p_j) puts them, within a
#: radius (px): (match or None, number of inliers)
GuidedMatcher = Callable[[FrameFeatures, FrameFeatures, np.ndarray, float], "tuple[PairMatch | None, int]"]


def guided_matcher(cfg: SlamConfig, K: np.ndarray, metric: str = "l2") -> GuidedMatcher:
    """Guided matching (:func:`projection_mask`) through the run's match filter and ratio test."""
    K = np.asarray(K, dtype=np.float64)

    def match(fi: FrameFeatures, fj: FrameFeatures, T_ij: np.ndarray, radius_px: float):
        a = explain_match(fi, fj, cfg.match_filter, metric, cfg.frontend.ratio,
                          allowed=projection_mask(fi, fj, T_ij, K, radius_px), K=K)
        return a.match, (a.match.n if a.match is not None else 0)

    return match
