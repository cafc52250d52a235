"""Trajectory metrics (docs/design.md, Evaluation).

- :func:`associate`: pair estimated and ground-truth frames by timestamp.
- :func:`umeyama`: least-squares similarity (or rigid) fit between point sets.
- :func:`ate`: absolute trajectory error after Sim(3) (scale, monocular) or SE(3) alignment.
- :func:`rpe`: relative pose error over a fixed frame delta.
- :func:`frame_motion`: the camera motion per frame of a trajectory (how hard a sequence is).
- :func:`evaluate_trajectory`: all of the above for one run, as a JSON-ready dict.

Poses are camera-to-world 4x4 matrices; all lengths are metres (callers print cm or mm);
rotation errors are reported in degrees where the field name says ``deg``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from c3f_slam.geometry import motion_magnitudes, relative_motion, relative_pose
from c3f_slam.matching.kabsch import kabsch

# ---------------------------------------------------------------------- association


def associate(t_est: np.ndarray, t_gt: np.ndarray, max_dt: float = 0.02) -> tuple[np.ndarray, np.ndarray]:
    """One-to-one pairs (idx_est, idx_gt) of timestamps closer than ``max_dt`` seconds.

    Exact matches always pair. Otherwise pairs are taken greedily by increasing |dt| (as
    TUM's ``associate.py``), each stamp used once. Returned sorted by estimated index.
    """
    t_est = np.asarray(t_est, dtype=np.float64).ravel()
    t_gt = np.asarray(t_gt, dtype=np.float64).ravel()
    if len(t_est) == 0 or len(t_gt) == 0:
        return np.zeros(0, int), np.zeros(0, int)
    order = np.argsort(t_gt)
    sorted_gt = t_gt[order]
    cands: list[tuple[float, int, int]] = []
    for i, t in enumerate(t_est):
        lo = np.searchsorted(sorted_gt, t - max_dt, side="left")
        hi = np.searchsorted(sorted_gt, t + max_dt, side="right")
        for k in range(lo, hi):
            cands.append((abs(sorted_gt[k] - t), i, int(order[k])))
    cands.sort()
    used_e, used_g, pairs = set(), set(), []
    for dt, i, j in cands:
        if dt <= max_dt and i not in used_e and j not in used_g:
            used_e.add(i)
            used_g.add(j)
            pairs.append((i, j))
    pairs.sort()
    if not pairs:
        return np.zeros(0, int), np.zeros(0, int)
    a = np.array(pairs, dtype=int)
    return a[:, 0], a[:, 1]


# ---------------------------------------------------------------------- alignment


def umeyama(src: np.ndarray, dst: np.ndarray, with_scale: bool = True) -> tuple[float, np.ndarray, np.ndarray]:
    """(s, R, t) minimising sum ||dst - (s R src + t)||^2 (Umeyama 1991); s = 1 if not ``with_scale``."""
    src = np.asarray(src, dtype=np.float64)
    dst = np.asarray(dst, dtype=np.float64)
    if src.shape != dst.shape or src.ndim != 2 or src.shape[1] != 3:
        raise ValueError(f"need two (N, 3) arrays of equal shape, got {src.shape} and {dst.shape}")
    if len(src) < 3:
        raise ValueError(f"alignment needs at least 3 positions, got {len(src)}")
    mu_s, mu_d = src.mean(0), dst.mean(0)
    xs, xd = src - mu_s, dst - mu_d
    # The best rotation does not depend on the scale: it is the (unweighted) Kabsch rotation.
    R = kabsch(src, dst)[:3, :3]
    if with_scale:
        var_s = (xs**2).sum() / len(src)
        if var_s <= 0:
            raise ValueError("source positions are all identical: scale undefined")
        # Umeyama's s = tr(D S) / var_s, i.e. tr(R H) / var_s with H the cross-covariance.
        s = float(np.trace(R @ (xs.T @ xd)) / len(src) / var_s)
    else:
        s = 1.0
    t = mu_d - s * R @ mu_s
    return s, R, t


def apply_sim3(s: float, R: np.ndarray, t: np.ndarray, poses: np.ndarray) -> np.ndarray:
    """Apply x -> s R x + t to camera-to-world poses (rotations rotate, positions move)."""
    out = np.array(poses, dtype=np.float64, copy=True)
    out[:, :3, :3] = R @ out[:, :3, :3]
    out[:, :3, 3] = s * out[:, :3, 3] @ R.T + t
    return out


@dataclass
class ErrorStats:
    """Summary of non-negative errors (same unit as the input)."""

    rmse: float
    mean: float
    median: float
    std: float
    max: float
    n: int

    @classmethod
    def of(cls, e: np.ndarray) -> ErrorStats:
        e = np.asarray(e, dtype=np.float64)
        if len(e) == 0:
            nan = float("nan")
            return cls(nan, nan, nan, nan, nan, 0)
        return cls(
            float(np.sqrt(np.mean(e**2))), float(e.mean()), float(np.median(e)), float(e.std()), float(e.max()), len(e)
        )

    def as_dict(self) -> dict:
        return dict(self.__dict__)


@dataclass(kw_only=True)
class ATEResult:
    """ATE (metres) after alignment ``mode``; ``errors`` per pose, ``aligned`` the moved estimate."""

    mode: str
    stats: ErrorStats
    scale: float
    R: np.ndarray
    t: np.ndarray
    errors: np.ndarray
    aligned: np.ndarray

    def as_dict(self) -> dict:
        stats = {f"{k}_m": v for k, v in self.stats.as_dict().items() if k != "n"}
        return {"align": self.mode, "scale": self.scale, **stats, "n": self.stats.n}


def ate(est_poses: np.ndarray, gt_poses: np.ndarray, align: str = "sim3") -> ATEResult:
    """Absolute trajectory error of associated camera-to-world poses (same length).

    ``align``: "sim3" (Umeyama with scale; monocular), "se3" (rigid) or "none".
    Errors are ||p_gt - (s R p_est + t)|| in metres.
    """
    est = np.asarray(est_poses, dtype=np.float64).reshape(-1, 4, 4)
    gt = np.asarray(gt_poses, dtype=np.float64).reshape(-1, 4, 4)
    if len(est) != len(gt):
        raise ValueError(f"{len(est)} estimated poses for {len(gt)} ground-truth poses")
    if align == "none":
        s, R, t = 1.0, np.eye(3), np.zeros(3)
    elif align in ("sim3", "se3"):
        s, R, t = umeyama(est[:, :3, 3], gt[:, :3, 3], with_scale=align == "sim3")
    else:
        raise ValueError(f"align must be sim3, se3 or none, got {align!r}")
    aligned = apply_sim3(s, R, t, est)
    err = np.linalg.norm(aligned[:, :3, 3] - gt[:, :3, 3], axis=1)
    return ATEResult(mode=align, stats=ErrorStats.of(err), scale=s, R=R, t=t, errors=err, aligned=aligned)


@dataclass
class RPEResult:
    """Relative pose error over ``delta`` frames: translation (m) and rotation (degrees)."""

    delta: int
    trans: ErrorStats
    rot_deg: ErrorStats

    def as_dict(self) -> dict:
        return {
            "delta": self.delta,
            **{f"trans_{k}_m": v for k, v in self.trans.as_dict().items() if k != "n"},
            **{f"rot_{k}_deg": v for k, v in self.rot_deg.as_dict().items() if k != "n"},
            "n": self.trans.n,
        }


def rpe(est_poses: np.ndarray, gt_poses: np.ndarray, delta: int = 1, scale: float = 1.0) -> RPEResult:
    """RPE of associated camera-to-world poses: E = inv(Q_i^-1 Q_{i+d}) (P_i^-1 P_{i+d}).

    ``scale`` multiplies estimated translations first (use the Sim(3) scale of :func:`ate`
    for monocular estimates).
    """
    est = np.array(est_poses, dtype=np.float64).reshape(-1, 4, 4)
    gt = np.asarray(gt_poses, dtype=np.float64).reshape(-1, 4, 4)
    if len(est) != len(gt):
        raise ValueError(f"{len(est)} estimated poses for {len(gt)} ground-truth poses")
    if delta < 1:
        raise ValueError(f"delta must be >= 1, got {delta}")
    est[:, :3, 3] *= scale
    n = len(est) - delta
    if n <= 0:
        return RPEResult(delta, ErrorStats.of(np.zeros(0)), ErrorStats.of(np.zeros(0)))
    d_est = relative_pose(est[:-delta], est[delta:])
    d_gt = relative_pose(gt[:-delta], gt[delta:])
    trans, rot = motion_magnitudes(relative_pose(d_gt, d_est))
    return RPEResult(delta, ErrorStats.of(trans), ErrorStats.of(rot))


def frame_motion(poses: np.ndarray, delta: int = 1) -> RPEResult:
    """Camera motion between frames i and i + ``delta`` of camera-to-world ``poses``:
    translation (m) and rotation (degrees), i.e. the RPE of a camera that never moves.

    Describes how hard a sequence is (per-frame baseline) for benchmarks and data reports.
    """
    trans, rot = relative_motion(poses, delta)
    return RPEResult(delta, ErrorStats.of(trans), ErrorStats.of(rot))


def path_length(positions: np.ndarray) -> float:
    """Length (metres) of the polyline through ``positions`` (N, 3), in order; 0 for N < 2."""
    P = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
    return float(np.linalg.norm(np.diff(P, axis=0), axis=1).sum())


def jitter_ratio(positions: np.ndarray, timestamps: np.ndarray, window_s: float = 1.0) -> float:
    """Path length of camera ``positions`` (N, 3) over the length of their moving average over
    ``window_s`` seconds (centred, by ``timestamps`` in seconds): 1 for a smooth path, larger the
    more the path shakes about its average. Both lengths are taken over the frames whose whole
    window lies inside the recording. Needs no ground truth. NaN for a path shorter than its
    window or whose average does not move."""
    p = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
    t = np.asarray(timestamps, dtype=np.float64).reshape(-1)
    ok = np.isfinite(p).all(axis=1) & np.isfinite(t)
    p, t = p[ok], t[ok]
    if len(p) < 3:
        return float("nan")
    csum = np.vstack([np.zeros((1, 3)), np.cumsum(p, axis=0)])
    lo = np.searchsorted(t, t - window_s / 2.0, side="left")
    hi = np.searchsorted(t, t + window_s / 2.0, side="right")
    smooth = (csum[hi] - csum[lo]) / (hi - lo)[:, None]
    inner = (t - window_s / 2.0 >= t[0]) & (t + window_s / 2.0 <= t[-1])  # whole windows only
    if inner.sum() < 2:
        return float("nan")
    base = path_length(smooth[inner])
    return path_length(p[inner]) / base if base > 0 else float("nan")


def registered_share(n_registered: int, n_frames: int) -> float:
    """Share of input frames that ended up registered (in the main component), in [0, 1]."""
    if n_frames <= 0:
        return 0.0
    return float(min(max(n_registered, 0), n_frames) / n_frames)


def evaluate_trajectory(
    est_stamps: np.ndarray,
    est_poses: np.ndarray,
    gt_stamps: np.ndarray,
    gt_poses: np.ndarray,
    n_frames: int | None = None,
    max_dt: float = 0.02,
    rpe_delta: int = 1,
) -> dict:
    """Associate, then ATE (Sim(3) and SE(3)), RPE (after the Sim(3) scale), registered share.

    ``n_frames``: number of input frames (default: number of ground-truth poses). Returns a
    JSON-ready dict; lengths in metres, rotations in degrees.
    """
    ie, ig = associate(est_stamps, gt_stamps, max_dt)
    total = len(gt_stamps) if n_frames is None else n_frames
    out: dict = {"n_associated": len(ie), "n_estimated": len(est_stamps),
                 "registered_share": registered_share(len(est_stamps), total)}
    if len(ie) < 3:
        out["error"] = f"only {len(ie)} poses associated with the ground truth (need 3)"
        return out
    E, G = np.asarray(est_poses)[ie], np.asarray(gt_poses)[ig]
    try:
        a_sim3, a_se3 = ate(E, G, "sim3"), ate(E, G, "se3")
    except ValueError as exc:  # e.g. a component whose frames all sit at one pose: no alignment
        out["error"] = f"ATE undefined: {exc}"
        return out
    out["ate_sim3"] = a_sim3.as_dict()
    out["ate_se3"] = a_se3.as_dict()
    out["rpe"] = rpe(E, G, rpe_delta, scale=a_sim3.scale).as_dict()
    out["gt_length_m"] = path_length(G[:, :3, 3])
    return out


def common_frames_ate(
    tracks: dict[str, tuple[np.ndarray, np.ndarray]], gt_stamps: np.ndarray, gt_poses: np.ndarray
) -> tuple[dict[str, float | None], int]:
    """ATE Sim(3) RMSE (metres) of each estimated trajectory over the frames that all of them
    registered (equal timestamps), each aligned on those frames alone, and the number of those frames.

    ``tracks``: name -> (timestamps (N,), camera-to-world poses (N, 4, 4)). A trajectory gets
    None when fewer than 3 frames are common or too few of them associate with the ground truth.
    Compares runs that register different parts of a sequence on the same frames.
    """
    common = set.intersection(*({float(t) for t in stamps} for stamps, _ in tracks.values()))
    rmse: dict[str, float | None] = {}
    for name, (stamps, poses) in tracks.items():
        keep = [k for k, t in enumerate(stamps) if float(t) in common]
        ev = evaluate_trajectory(stamps[keep], poses[keep], gt_stamps, gt_poses) if len(keep) >= 3 else {}
        rmse[name] = ev["ate_sim3"]["rmse_m"] if "ate_sim3" in ev else None
    return rmse, len(common)
