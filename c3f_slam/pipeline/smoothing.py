"""A constant-velocity motion prior on the final camera path (``smoothing.motion_prior_s``;
docs/design.md, Smooth trajectories on predicted depth).

On predicted depth each frame's registration is off by about as much as the camera moves
between two frames, so the path of the graph's poses zigzags about the true one. After the
final optimisation the poses of each component's registered frames, in stream order, are
refitted: the positions x_i (and, the same way, the orientations' unit quaternions, sign-aligned
along the path and normalised afterwards) minimise

    sum_i w_i |x_i - y_i|^2  +  tau^4 sum_i w_i r_i |a_i|^2

with y_i the graph's pose, a_i the second divided difference (the acceleration, by the
timestamps), w_i the time each frame stands for (half the gaps to its neighbours) and r_i a
robust weight: a Whittaker-Henderson smoother, continuous in time, so its cut-off does not
depend on the frame rate or on skipped frames. A path at constant velocity passes unchanged at
any speed; velocity changes faster than about 1 / tau rad/s are damped (gain 1 / (1 + (omega
tau)^4)), unless they are far larger than the path's usual ones: the weights r_i are Huber's
(iteratively reweighted, ``robust_iterations`` passes): 1 while the smoothed path's
acceleration at frame i, in position or in orientation, is within ``robust_k`` times its median
over the path, and robust_k x median / acceleration beyond, so that a true turn or burst of the
camera keeps most of its sharpness. The system is banded (five diagonals), so a path of N frames
costs O(N) per pass. The path is smoothed piecewise: no prior across a gap longer than
``max_gap_s`` between registered frames.
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import solveh_banded
from scipy.spatial.transform import Rotation


def path_pieces(stamps: np.ndarray, max_gap_s: float) -> list[np.ndarray]:
    """Index ranges (arrays, in order) of the stretches of ``stamps`` (seconds, increasing) with
    no gap longer than ``max_gap_s`` (a gap that does not increase the time splits too)."""
    t = np.asarray(stamps, dtype=np.float64).reshape(-1)
    if not len(t):
        return []
    dt = np.diff(t)
    cuts = np.flatnonzero((dt > max_gap_s) | ~(dt > 0)) + 1
    return np.split(np.arange(len(t)), cuts)


class PathSmoother:
    """The banded least-squares system of one stretch of ``stamps`` (N >= 3, strictly
    increasing seconds) for time constant ``time_constant_s``, in units of the median time step
    (well scaled whatever the frame rate): :meth:`solve` for given robust weights,
    :meth:`accelerations` of a solution."""

    def __init__(self, stamps: np.ndarray, time_constant_s: float) -> None:
        t = np.asarray(stamps, dtype=np.float64)
        self.n = n = len(t)
        h = np.diff(t)
        h = h / float(np.median(h))
        self.tau4 = (time_constant_s / float(np.median(np.diff(t)))) ** 4
        w = np.zeros(n)  # the time each frame stands for
        w[:-1] += 0.5 * h
        w[1:] += 0.5 * h
        self.w = w
        # second divided differences: a_i = c0 x_{i-1} + c1 x_i + c2 x_{i+1}, i = 1 .. n-2
        h0, h1 = h[:-1], h[1:]
        s = 2.0 / (h0 + h1)
        self.c = np.stack([s / h0, -s * (1.0 / h0 + 1.0 / h1), s / h1], axis=1)  # (n-2, 3)

    def solve(self, Y: np.ndarray, robust: np.ndarray | None = None) -> np.ndarray:
        """The smoothed columns of ``Y`` (N, k) with the acceleration terms weighted by
        ``robust`` (N-2,; None: 1)."""
        n, c = self.n, self.c
        wa = self.tau4 * self.w[1:-1] * (1.0 if robust is None else robust)
        ab = np.zeros((3, n))  # upper form: ab[2 + i - j, j] = M[i, j] for i <= j
        ab[2] = self.w
        idx = np.arange(n - 2)
        for r in range(3):  # row i-1+r of D^T W_a D gets c_r c_q wa for column i-1+q
            for q in range(r, 3):
                np.add.at(ab, (2 + r - q, idx + q), c[:, r] * c[:, q] * wa)
        return solveh_banded(ab, self.w[:, None] * Y, check_finite=False)

    def accelerations(self, X: np.ndarray) -> np.ndarray:
        """(N-2, k) second divided differences of the columns of ``X`` (N, k)."""
        c = self.c
        return c[:, :1] * X[:-2] + c[:, 1:2] * X[1:-1] + c[:, 2:] * X[2:]


def huber_weights(accel: list[np.ndarray], k: float) -> np.ndarray:
    """Huber weights (M,) of the acceleration rows of each array in ``accel`` ((M, d) each: the
    position's, the orientation's): each row's norm over its array's median norm, the largest of
    those ratios per row, weight 1 up to ``k`` and k / ratio beyond."""
    ratio = np.zeros(len(accel[0]))
    for a in accel:
        norm = np.linalg.norm(a, axis=1)
        med = float(np.median(norm))
        if med > 0:
            ratio = np.maximum(ratio, norm / med)
    return np.where(ratio > k, k / np.maximum(ratio, 1e-300), 1.0)


def smooth_piece(stamps: np.ndarray, poses: np.ndarray, time_constant_s: float, robust_k: float = 0.0,
                 robust_iterations: int = 3) -> np.ndarray:
    """The poses (N, 4, 4, camera-to-world) of one stretch without long gaps, smoothed (see
    the module notes; ``robust_k`` 0: no robust weights); fewer than 3 poses or tau 0:
    unchanged (a copy)."""
    P = np.array(poses, dtype=np.float64)
    n = len(P)
    if n < 3 or time_constant_s <= 0:
        return P
    q = Rotation.from_matrix(P[:, :3, :3]).as_quat()
    flip = np.cumprod(np.where(np.einsum("ij,ij->i", q[1:], q[:-1]) < 0, -1.0, 1.0))
    q[1:] *= flip[:, None]  # one hemisphere along the path
    system = PathSmoother(stamps, time_constant_s)
    Y = np.hstack([P[:, :3, 3], q])
    X = system.solve(Y)
    for _ in range(robust_iterations if robust_k > 0 else 0):
        a = system.accelerations(X)
        X = system.solve(Y, huber_weights([a[:, :3], a[:, 3:]], robust_k))
    out = P.copy()
    out[:, :3, 3] = X[:, :3]
    out[:, :3, :3] = Rotation.from_quat(X[:, 3:] / np.linalg.norm(X[:, 3:], axis=1, keepdims=True)).as_matrix()
    return out


def smooth_poses(stamps: np.ndarray, poses: np.ndarray, time_constant_s: float, *, max_gap_s: float = 0.5,
                 robust_k: float = 0.0, robust_iterations: int = 3) -> np.ndarray:
    """``poses`` (N, 4, 4, camera-to-world, metres; one component's registered frames in stream
    order with their ``stamps`` in seconds) under the constant-velocity prior of time constant
    ``time_constant_s`` (seconds; 0: unchanged), piece by piece between gaps longer than
    ``max_gap_s`` (:func:`path_pieces`), with Huber weights at ``robust_k`` times the median
    acceleration (0: none; see the module notes). Returns a new array."""
    P = np.array(poses, dtype=np.float64).reshape(-1, 4, 4)
    t = np.asarray(stamps, dtype=np.float64).reshape(-1)
    if len(t) != len(P):
        raise ValueError(f"{len(t)} timestamps for {len(P)} poses")
    if time_constant_s <= 0:
        return P
    for piece in path_pieces(t, max_gap_s):
        P[piece] = smooth_piece(t[piece], P[piece], time_constant_s, robust_k, robust_iterations)
    return P
