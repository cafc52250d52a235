"""What is tried where plain sparse matching to the previous frame failed:
guided matching, then, optionally, dense RGB-D alignment, then the motion bridge
(:class:`LinkRecovery`).

Guided matching (:func:`c3f_slam.pipeline.frontend.guided_matcher`) matches again with the last
inter-frame motion as a prior, each keypoint only against the keypoints near where the prior
puts it; the same match filter verifies it, so its result is an ordinary link.

When the previous frame and the current one still give no accepted sparse match (too few
keypoints, blur, a texture-poor view), :class:`DenseFallback` aligns them with Open3D's
RGB-D odometry (the hybrid photometric + geometric term, Steinbruecker et al. / Park et
al.), starting from the last inter-frame motion, then **verifies** the result on its own
residuals: the current frame's depth pixels, moved into the previous frame, must land on its
depth (relative depth difference) with matching intensity, on a large enough share of the
pixels, and the motion must be plausible for consecutive frames. A verified alignment
becomes an uncertain ``fallback`` edge whose information matrix is ``trust`` x that of its
verified points (:func:`c3f_slam.posegraph.information.information_from_points`): it keeps
the map in one piece when nothing contradicts it, and the line process prunes it when loop or
rejoin edges disagree.

Where neither gave a link, :class:`MotionBridge` places the frame where the last link's motion
puts it (constant velocity, scaled to the time between the frames): a colonoscope cannot jump
in 1/30 s, and on a smooth wall or while a fold sweeps through the view the features fail for a
frame or two while the camera moves on as before. The predicted pose passes the same residual
checks as a dense alignment (they reject a cut in the video, or a frame after a stop), and it
becomes a ``fallback`` edge of the same trust, at most ``bridge_max_frames`` frames in a row.

Only the previous processed frame's grey image and depth are kept (one frame of memory).
Poses and transforms follow :mod:`c3f_slam.posegraph`: ``T_ij`` maps frame-j (current)
points into frame i (previous), p_i = T_ij p_j, metres.
"""

from __future__ import annotations

from collections import Counter, deque
from dataclasses import dataclass, replace

import cv2
import numpy as np
import open3d as o3d
from scipy.spatial.transform import Rotation

from c3f_slam.config import FallbackConfig, SlamConfig
from c3f_slam.geometry import backproject_pixels, motion_magnitudes, project, transform_points
from c3f_slam.pipeline.frontend import FrameFeatures, GuidedMatcher, PairMatch, guided_matcher
from c3f_slam.posegraph.information import information_from_points

#: the longest a bridge reaches, in mean steps of the links its velocity comes from (two frames skipped)
MAX_BRIDGE_STEPS = 3

#: pixel grid of the verification (every STRIDE-th pixel in each direction)
STRIDE = 2


@dataclass
class RgbdFrame:
    """A frame as the fallback keeps it: grey (H, W) float32 in 0..1, depth (H, W) float32 metres (NaN/0 = none)."""

    gray: np.ndarray
    depth: np.ndarray

    @classmethod
    def from_rgb(cls, rgb: np.ndarray, depth: np.ndarray) -> RgbdFrame:
        gray = cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2GRAY).astype(np.float32) / 255.0
        d = np.nan_to_num(np.asarray(depth, dtype=np.float32), nan=0.0, posinf=0.0, neginf=0.0)
        return cls(gray, np.where(d > 0, d, 0.0).astype(np.float32))


@dataclass(frozen=True)
class Verification:
    """Residuals of an alignment: share of the current frame's sampled depth pixels that land on
    the previous frame's depth, their intensity RMSE (0..1), and the aligned motion."""

    inlier_share: float
    photometric_rmse: float
    step_m: float
    turn_deg: float
    points_j: np.ndarray  # (N, 3) inlier points of the current frame j, metres

    def failure(self, cfg: FallbackConfig) -> str | None:
        """Why the alignment is rejected (None: accepted)."""
        if self.step_m > cfg.max_step or self.turn_deg > cfg.max_turn_deg:
            return "implausible_motion"
        if self.inlier_share < cfg.min_inlier_share:
            return "low_overlap"
        if self.photometric_rmse > cfg.max_photometric_rmse:
            return "photometric_residual"
        return None


def verify_alignment(T_ij: np.ndarray, prev: RgbdFrame, cur: RgbdFrame, K: np.ndarray,
                     max_depth_residual: float) -> Verification:
    """Move the current frame's depth pixels (every :data:`STRIDE`-th) by ``T_ij`` into the
    previous frame and compare depth (|dz| <= ``max_depth_residual`` x depth) and intensity."""
    h, w = cur.depth.shape
    v, u = np.mgrid[0:h:STRIDE, 0:w:STRIDE]
    z = cur.depth[v, u]
    ok = z > 0
    u, v = u[ok], v[ok]
    pts_j = backproject_pixels(np.stack([u, v], axis=1), z[ok], K)
    step, turn = (float(x[0]) for x in motion_magnitudes(T_ij[None]))
    if len(pts_j) == 0:
        return Verification(0.0, float("inf"), step, turn, np.zeros((0, 3)))
    uv, z_i = project(transform_points(T_ij, pts_j), K)
    px = np.round(np.nan_to_num(uv, nan=-1.0)).astype(np.int64)
    inside = (z_i > 1e-6) & (px[:, 0] >= 0) & (px[:, 0] < w) & (px[:, 1] >= 0) & (px[:, 1] < h)
    ui, vi = np.where(inside, px[:, 0], 0), np.where(inside, px[:, 1], 0)
    z_prev = np.where(inside, prev.depth[vi, ui], 0.0)
    inlier = inside & (z_prev > 0) & (np.abs(z_prev - z_i) <= max_depth_residual * z_i)
    if not inlier.any():
        return Verification(0.0, float("inf"), step, turn, np.zeros((0, 3)))
    di = prev.gray[vi[inlier], ui[inlier]] - cur.gray[v[inlier], u[inlier]]
    rmse = float(np.sqrt(np.mean(np.square(di - np.mean(di)))))  # a global brightness change is not a misfit
    return Verification(float(inlier.mean()), rmse, step, turn, pts_j[inlier])


def fallback_information(m: PairMatch, cfg: FallbackConfig) -> np.ndarray:
    """The 6x6 information matrix (Open3D order) of a fallback edge: ``cfg.trust`` x that of its
    verified points."""
    return cfg.trust * information_from_points(m.points_j)


def verified_edge(T_ij: np.ndarray, prev: RgbdFrame, cur: RgbdFrame, K: np.ndarray, cfg: FallbackConfig, *,
                  bounds: FallbackConfig, outcomes: Counter[str]) -> PairMatch | None:
    """``T_ij`` as a fallback edge if it passes :meth:`Verification.failure` under ``bounds``
    (counted in ``outcomes``), else None: its verified points, evenly subsampled to
    ``cfg.points``, and the inlier count it ranks as beside sparse matches (``cfg.trust`` x
    points, at least 1)."""
    check = verify_alignment(T_ij, prev, cur, K, cfg.max_depth_residual)
    why = check.failure(bounds)
    outcomes[why or "accepted"] += 1
    if why is not None:
        return None
    pts = check.points_j
    if len(pts) > cfg.points:
        pts = pts[np.linspace(0, len(pts) - 1, cfg.points).astype(int)]
    return PairMatch(T_ij, pts, max(1, round(cfg.trust * len(pts))))


class DenseFallback:
    """Keeps the previous processed frame and aligns the current one to it on demand."""

    def __init__(self, cfg: FallbackConfig, K: np.ndarray) -> None:
        self.cfg = cfg
        self.K = np.asarray(K, dtype=np.float64)
        self.prev: RgbdFrame | None = None
        self.outcomes: Counter[str] = Counter()

    def remember(self, frame: RgbdFrame | None) -> None:
        """The frame just processed becomes the one the next alignment starts from (None: a gap)."""
        self.prev = frame

    def align(self, cur: RgbdFrame, init: np.ndarray | None = None) -> PairMatch | None:
        """T_prev,cur for the current frame, verified (see the module notes), or None."""
        if self.prev is None:
            return None
        T = self.odometry(self.prev, cur, np.eye(4) if init is None else init)
        if T is None:
            self.outcomes["no_convergence"] += 1
            return None
        return verified_edge(T, self.prev, cur, self.K, self.cfg, bounds=self.cfg, outcomes=self.outcomes)

    def strength(self, n_points: int) -> int:
        """The inlier count a fallback edge of ``n_points`` verified points ranks as beside sparse
        matches (``trust`` x points, at least 1)."""
        return max(1, round(self.cfg.trust * n_points))

    def information(self, m: PairMatch) -> np.ndarray:
        """The trust-weighted 6x6 information matrix of a fallback edge (:func:`fallback_information`)."""
        return fallback_information(m, self.cfg)

    def odometry(self, prev: RgbdFrame, cur: RgbdFrame, init: np.ndarray) -> np.ndarray | None:
        """Open3D hybrid RGB-D odometry of ``cur`` (source) onto ``prev`` (target); None if it fails."""
        h, w = cur.depth.shape
        valid = cur.depth[cur.depth > 0]
        if len(valid) < 100:
            return None
        depth_max = float(np.percentile(valid, 99)) * 1.5
        intr = o3d.camera.PinholeCameraIntrinsic(w, h, self.K[0, 0], self.K[1, 1], self.K[0, 2], self.K[1, 2])
        option = o3d.pipelines.odometry.OdometryOption(  # depth_diff_max ~ 10 % of the depth
            o3d.utility.IntVector([20, 10, 5]), 0.1 * float(np.median(valid)), 0.0, depth_max)
        src, dst = (o3d.geometry.RGBDImage.create_from_color_and_depth(
            o3d.geometry.Image(f.gray), o3d.geometry.Image(f.depth), depth_scale=1.0, depth_trunc=depth_max,
            convert_rgb_to_intensity=False) for f in (cur, prev))
        ok, T, _ = o3d.pipelines.odometry.compute_rgbd_odometry(
            src, dst, intr, np.asarray(init, dtype=np.float64),
            o3d.pipelines.odometry.RGBDOdometryJacobianFromHybridTerm(), option)
        T = np.asarray(T, dtype=np.float64)
        return T if ok and np.all(np.isfinite(T)) else None

    def stats(self) -> dict:
        """Counters for summary.json: attempts and their outcomes."""
        return {"fallback_attempts": int(sum(self.outcomes.values())),
                "fallback_outcomes": dict(sorted(self.outcomes.items()))}


def _left_jacobian(rotvec: np.ndarray) -> np.ndarray:
    """SO(3)'s left Jacobian V(w): the translation of exp([w, u]) is V(w) u."""
    theta = float(np.linalg.norm(rotvec))
    W = np.array([[0.0, -rotvec[2], rotvec[1]], [rotvec[2], 0.0, -rotvec[0]], [-rotvec[1], rotvec[0], 0.0]])
    if theta < 1e-8:
        return np.eye(3) + 0.5 * W
    return (np.eye(3) + (1 - np.cos(theta)) / theta**2 * W
            + (theta - np.sin(theta)) / theta**3 * W @ W)


def scaled_motion(T: np.ndarray, ratio: float) -> np.ndarray:
    """The rigid motion ``T`` (4x4) continued at constant velocity (a constant twist) for
    ``ratio`` times its duration: exp(ratio log T) on SE(3)."""
    w = Rotation.from_matrix(T[:3, :3]).as_rotvec()
    u = np.linalg.solve(_left_jacobian(w), T[:3, 3])
    out = np.eye(4)
    out[:3, :3] = Rotation.from_rotvec(w * ratio).as_matrix()
    out[:3, 3] = _left_jacobian(w * ratio) @ (u * ratio)
    return out


class MotionBridge:
    """Places a frame that nothing linked by the camera's velocity (see the module notes).

    The velocity is the mean over the last ``bridge_window`` links in a row (one link on predicted
    depth can be off by several degrees). State: the previous processed frame
    (:class:`RgbdFrame`) and time stamp, those links' T_prev,cur and the seconds each spanned
    (emptied by a processed frame without a link; skipped frames keep them), and the number of
    frames bridged in a row."""

    def __init__(self, cfg: FallbackConfig, K: np.ndarray) -> None:
        self.cfg = cfg
        self.checks = replace(cfg, min_inlier_share=cfg.bridge_min_inlier_share,
                              max_photometric_rmse=cfg.bridge_max_photometric_rmse)
        self.K = np.asarray(K, dtype=np.float64)
        self.prev: RgbdFrame | None = None
        self.stamp: float | None = None
        self.links: deque[tuple[np.ndarray, float]] = deque(maxlen=cfg.bridge_window)
        self.in_row = 0
        self.outcomes: Counter[str] = Counter()

    def predict(self, stamp: float) -> tuple[np.ndarray, float] | None:
        """T_prev,cur at time ``stamp`` (seconds) under constant velocity, and the steps it
        spans (the time in mean steps of the links it comes from, at least 1); or None."""
        if not self.links or self.stamp is None or self.in_row >= self.cfg.bridge_max_frames:
            return None
        T, seconds = np.eye(4), 0.0
        for T_step, dt_step in self.links:  # oldest first: T_{k-n,k} = T_{k-n,k-n+1} ... T_{k-1,k}
            T, seconds = T @ T_step, seconds + dt_step
        dt = stamp - self.stamp
        steps = dt / (seconds / len(self.links))
        if not 0 < steps <= MAX_BRIDGE_STEPS + 0.01:  # 0.01: time stamps' rounding
            return None
        return scaled_motion(T, dt / seconds), max(1.0, steps)

    def link(self, cur: RgbdFrame, stamp: float) -> PairMatch | None:
        """The verified bridge T_prev,cur of ``cur`` (taken at ``stamp`` seconds), or None. The
        plausible motion (``max_step``, ``max_turn_deg``) grows with the steps it spans (frames
        skipped since the previous processed one)."""
        predicted = self.predict(stamp) if self.prev is not None else None
        if predicted is None:
            return None
        assert self.prev is not None
        T, steps = predicted
        bounds = replace(self.checks, max_step=self.cfg.max_step * steps,
                         max_turn_deg=min(180.0, self.cfg.max_turn_deg * steps))
        return verified_edge(T, self.prev, cur, self.K, self.cfg, bounds=bounds, outcomes=self.outcomes)

    def remember(self, frame: RgbdFrame | None, stamp: float, link: PairMatch | None, bridged: bool) -> None:
        """The frame just processed (at ``stamp`` seconds), placed by ``link`` (a bridge when
        ``bridged``; None: no link, the motion is unknown)."""
        if link is not None and self.stamp is not None and stamp > self.stamp:
            self.links.append((link.T_ij, stamp - self.stamp))
        else:
            self.links.clear()
        self.in_row = self.in_row + 1 if bridged else 0
        self.prev, self.stamp = frame, stamp

    def stats(self) -> dict:
        """Counters for summary.json: attempts and their outcomes."""
        return {"bridge_attempts": int(sum(self.outcomes.values())),
                "bridge_outcomes": dict(sorted(self.outcomes.items()))}


class LinkRecovery:
    """Guided matching and the dense fallback of one run, with the last inter-frame motion
    (T_prev,cur, metres) they start from. Tests may replace ``guided`` (a
    :data:`~c3f_slam.pipeline.frontend.GuidedMatcher`) and ``dense``."""

    def __init__(self, cfg: SlamConfig, K: np.ndarray, metric: str = "l2") -> None:
        self.cfg = cfg.fallback
        self.guided: GuidedMatcher = guided_matcher(cfg, K, metric)
        self.dense = DenseFallback(cfg.fallback, K) if cfg.fallback.dense else None
        self.bridge = MotionBridge(cfg.fallback, K) if cfg.fallback.bridge else None
        self.last_motion = np.eye(4)
        self.guided_links = 0

    def guided_link(self, prev: FrameFeatures, cur: FrameFeatures, image_side: int) -> tuple[PairMatch | None, int]:
        """Guided matching of ``cur`` to ``prev`` (``image_side``: the smaller side, px, for the
        search radius); (None, 0) when it is off or finds nothing."""
        if not self.cfg.guided:
            return None, 0
        link, n = self.guided(prev, cur, self.last_motion, self.cfg.guided_radius * image_side)
        self.guided_links += link is not None
        return link, n

    def frame(self, rgb: np.ndarray | None, depth: np.ndarray) -> RgbdFrame | None:
        """The frame as the dense fallback and the bridge keep it (None when both are off or it
        has no image)."""
        wanted = self.dense is not None or self.bridge is not None
        return RgbdFrame.from_rgb(rgb, depth) if wanted and rgb is not None else None

    def dense_link(self, frame: RgbdFrame | None) -> PairMatch | None:
        """The verified dense alignment T_prev,cur of ``frame`` to the previous frame, or None."""
        if self.dense is None or frame is None:
            return None
        return self.dense.align(frame, self.last_motion)

    def bridge_link(self, frame: RgbdFrame | None, stamp: float) -> PairMatch | None:
        """The verified constant-velocity T_prev,cur of ``frame`` (at ``stamp`` seconds), or None."""
        if self.bridge is None or frame is None:
            return None
        return self.bridge.link(frame, stamp)

    def information(self, m: PairMatch) -> np.ndarray:
        """The information matrix of a dense or bridge edge (:func:`fallback_information`)."""
        return fallback_information(m, self.cfg)

    def settle(self, link: PairMatch | None, frame: RgbdFrame | None, stamp: float, bridged: bool = False) -> None:
        """The frame (at ``stamp`` seconds) was placed by ``link`` (None: without one, or it
        opened a lone fragment; ``bridged``: ``link`` is the bridge's)."""
        self.last_motion = link.T_ij if link is not None else np.eye(4)
        if self.dense is not None:
            self.dense.remember(frame)
        if self.bridge is not None:
            self.bridge.remember(frame, stamp, link, bridged)

    def gap(self) -> None:
        """A frame was skipped: nothing to align the next one to densely. The bridge keeps the
        last processed frame: the camera moved on at about its velocity (its prediction spans
        at most three of its mean steps)."""
        self.last_motion = np.eye(4)
        if self.dense is not None:
            self.dense.remember(None)

    def stats(self) -> dict:
        """Counters for summary.json."""
        dense = self.dense.stats() if self.dense is not None else {"fallback_attempts": 0}
        bridge = self.bridge.stats() if self.bridge is not None else {"bridge_attempts": 0}
        return {"guided_links": self.guided_links, **dense, **bridge}
