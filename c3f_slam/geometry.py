"""Rigid-body geometry in NumPy (the torch-free half of the project's geometry).

Conventions, used everywhere in the project:
- A pose is a 4x4 homogeneous matrix. ``T_wc`` (camera-to-world) maps camera coordinates
  to world coordinates: p_w = T_wc @ p_c. Trajectories store camera-to-world poses.
- ``T_ij`` maps coordinates of frame j into frame i: p_i = T_ij @ p_j, and
  T_ij = inv(T_wi) @ T_wj.
- Angles are radians. Axis-angle vectors have the rotation angle as their norm. The
  motion magnitudes at the end (:func:`motion_magnitudes`, :func:`relative_motion`) report
  degrees, as every metric and report of the project prints rotations.
- Quaternions are (qx, qy, qz, qw), the TUM order, unit norm.
- Camera frame: x right, y down, z forward (OpenCV). Depth is z in metres.

The torch counterparts for training live in ``c3f_models.geometry`` and follow the same
conventions; tests check both against the same hand-computed cases.
"""

from __future__ import annotations

import numpy as np

# ---------------------------------------------------------------------- SE(3)


def make_pose(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """4x4 pose from a 3x3 rotation and a 3-vector translation."""
    T = np.eye(4, dtype=np.float64)
    T[:3, :3] = R
    T[:3, 3] = np.asarray(t, dtype=np.float64).reshape(3)
    return T


def invert_pose(T: np.ndarray) -> np.ndarray:
    """Inverse of a rigid transform (or a stack ``(..., 4, 4)``), using R^T."""
    T = np.asarray(T, dtype=np.float64)
    R = T[..., :3, :3]
    t = T[..., :3, 3:]
    Rt = np.swapaxes(R, -1, -2)
    out = np.zeros_like(T)
    out[..., :3, :3] = Rt
    out[..., :3, 3:] = -Rt @ t
    out[..., 3, 3] = 1.0
    return out


def compose(*Ts: np.ndarray) -> np.ndarray:
    """Product T1 @ T2 @ ... of rigid transforms."""
    out = np.eye(4)
    for T in Ts:
        out = out @ T
    return out


def relative_pose(T_wi: np.ndarray, T_wj: np.ndarray) -> np.ndarray:
    """T_ij = inv(T_wi) @ T_wj: maps frame-j coordinates into frame i."""
    return invert_pose(T_wi) @ T_wj


def transform_points(T: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Apply a 4x4 transform to (N, 3) points."""
    points = np.asarray(points, dtype=np.float64)
    return points @ T[:3, :3].T + T[:3, 3]


def is_rotation(R: np.ndarray, atol: float = 1e-6) -> bool:
    """True when R is orthonormal with determinant +1."""
    R = np.asarray(R, dtype=np.float64)
    return bool(np.allclose(R.T @ R, np.eye(3), atol=atol) and abs(np.linalg.det(R) - 1) < atol)


# ---------------------------------------------------------------------- rotations


def _skew(v: np.ndarray) -> np.ndarray:
    x, y, z = v
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def axis_angle_to_matrix(rotvec: np.ndarray) -> np.ndarray:
    """Rodrigues: 3-vector (axis * angle, radians) to a 3x3 rotation matrix."""
    rotvec = np.asarray(rotvec, dtype=np.float64).reshape(3)
    theta = float(np.linalg.norm(rotvec))
    if theta < 1e-12:
        return np.eye(3) + _skew(rotvec)
    k = _skew(rotvec / theta)
    return np.eye(3) + np.sin(theta) * k + (1 - np.cos(theta)) * (k @ k)


def matrix_to_axis_angle(R: np.ndarray) -> np.ndarray:
    """Inverse of :func:`axis_angle_to_matrix`; angle in [0, pi]."""
    return quaternion_to_axis_angle(matrix_to_quaternion(R))


def quaternion_to_axis_angle(q: np.ndarray) -> np.ndarray:
    q = np.asarray(q, dtype=np.float64)
    q = q / np.linalg.norm(q)
    if q[3] < 0:
        q = -q
    v, w = q[:3], q[3]
    s = np.linalg.norm(v)
    if s < 1e-12:
        return 2.0 * v
    angle = 2.0 * np.arctan2(s, w)
    return v / s * angle


def quaternion_to_matrix(q: np.ndarray) -> np.ndarray:
    """(qx, qy, qz, qw) to a 3x3 rotation; the quaternion is normalised first."""
    q = np.asarray(q, dtype=np.float64).reshape(4)
    n = np.linalg.norm(q)
    if not np.isfinite(n) or n < 1e-12:
        raise ValueError(f"quaternion {q} has zero or non-finite norm")
    x, y, z, w = q / n
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def matrix_to_quaternion(R: np.ndarray) -> np.ndarray:
    """3x3 rotation to (qx, qy, qz, qw) with qw >= 0 (Shepperd's method)."""
    R = np.asarray(R, dtype=np.float64)
    tr = np.trace(R)
    if tr > 0:
        s = 2.0 * np.sqrt(tr + 1.0)
        w = 0.25 * s
        x = (R[2, 1] - R[1, 2]) / s
        y = (R[0, 2] - R[2, 0]) / s
        z = (R[1, 0] - R[0, 1]) / s
    elif R[0, 0] > R[1, 1] and R[0, 0] > R[2, 2]:
        s = 2.0 * np.sqrt(1.0 + R[0, 0] - R[1, 1] - R[2, 2])
        w = (R[2, 1] - R[1, 2]) / s
        x = 0.25 * s
        y = (R[0, 1] + R[1, 0]) / s
        z = (R[0, 2] + R[2, 0]) / s
    elif R[1, 1] > R[2, 2]:
        s = 2.0 * np.sqrt(1.0 + R[1, 1] - R[0, 0] - R[2, 2])
        w = (R[0, 2] - R[2, 0]) / s
        x = (R[0, 1] + R[1, 0]) / s
        y = 0.25 * s
        z = (R[1, 2] + R[2, 1]) / s
    else:
        s = 2.0 * np.sqrt(1.0 + R[2, 2] - R[0, 0] - R[1, 1])
        w = (R[1, 0] - R[0, 1]) / s
        x = (R[0, 2] + R[2, 0]) / s
        y = (R[1, 2] + R[2, 1]) / s
        z = 0.25 * s
    q = np.array([x, y, z, w])
    q /= np.linalg.norm(q)
    return -q if q[3] < 0 else q


def look_at(eye: np.ndarray, target: np.ndarray, up: np.ndarray) -> np.ndarray:
    """Camera-to-world pose of a camera at ``eye`` whose +z looks at ``target``.

    ``up`` is the world direction that should appear *up* in the image (camera -y).
    """
    eye = np.asarray(eye, dtype=np.float64)
    z = np.asarray(target, dtype=np.float64) - eye
    z /= np.linalg.norm(z)
    x = np.cross(-np.asarray(up, dtype=np.float64), z)  # x = y x z with y = -up
    nx = np.linalg.norm(x)
    if nx < 1e-9:
        raise ValueError("look_at: up is parallel to the viewing direction")
    x /= nx
    y = np.cross(z, x)
    return make_pose(np.stack([x, y, z], axis=1), eye)


# ---------------------------------------------------------------------- projection


def backproject(depth: np.ndarray, K: np.ndarray) -> np.ndarray:
    """(H, W) depth in metres to (H, W, 3) camera-frame points (z = depth)."""
    h, w = depth.shape
    u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    z = depth.astype(np.float64)
    x = (u - K[0, 2]) / K[0, 0] * z
    y = (v - K[1, 2]) / K[1, 1] * z
    return np.stack([x, y, z], axis=-1)


def backproject_pixels(uv: np.ndarray, depth: np.ndarray, K: np.ndarray) -> np.ndarray:
    """(N, 2) pixel coordinates (u, v) with (N,) depths to (N, 3) camera-frame points."""
    uv = np.asarray(uv, dtype=np.float64)
    z = np.asarray(depth, dtype=np.float64)
    x = (uv[:, 0] - K[0, 2]) / K[0, 0] * z
    y = (uv[:, 1] - K[1, 2]) / K[1, 1] * z
    return np.stack([x, y, z], axis=-1)


def project(points: np.ndarray, K: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(N, 3) camera-frame points to (N, 2) pixels (u, v) and their (N,) depths z.

    Points with z <= 0 get NaN pixel coordinates.
    """
    points = np.asarray(points, dtype=np.float64)
    z = points[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        u = K[0, 0] * points[:, 0] / z + K[0, 2]
        v = K[1, 1] * points[:, 1] / z + K[1, 2]
    uv = np.stack([u, v], axis=-1)
    uv[z <= 0] = np.nan
    return uv, z


# ---------------------------------------------------------------------- curves


def transport_frames(tangents: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rotation-minimising (parallel-transport) frames along a curve.

    ``tangents``: (N, 3) unit tangents at consecutive samples. Returns normals N and binormals
    B = T x N, (N, 3) each: N starts perpendicular to T[0] (from the world z axis, or x when
    T[0] is near z) and is carried along by projecting it onto each next normal plane, so the
    frame does not twist about the curve.
    """
    t = np.asarray(tangents, dtype=np.float64)
    n = np.empty_like(t)
    a = np.array([0.0, 0.0, 1.0]) if abs(t[0, 2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    n0 = a - t[0] * (a @ t[0])
    n[0] = n0 / np.linalg.norm(n0)
    for j in range(1, len(t)):
        v = n[j - 1] - t[j] * (n[j - 1] @ t[j])
        n[j] = v / np.linalg.norm(v)
    return n, np.cross(t, n)


# ---------------------------------------------------------------------- motion between poses


def motion_magnitudes(T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Translation length (m) and rotation angle (degrees) of each rigid transform of (N, 4, 4) ``T``."""
    T = np.asarray(T, dtype=np.float64).reshape(-1, 4, 4)
    trans = np.linalg.norm(T[:, :3, 3], axis=1)
    rot = np.degrees([np.linalg.norm(matrix_to_axis_angle(M[:3, :3])) for M in T]).reshape(-1)
    return trans, rot


def relative_motion(poses: np.ndarray, delta: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Per pair of camera-to-world poses (i, i + ``delta``): the camera's translation (m) and
    rotation (degrees) between them, (N - delta,) each;
    :func:`c3f_slam.evaluation.trajectory.frame_motion` summarises them."""
    P = np.asarray(poses, dtype=np.float64).reshape(-1, 4, 4)
    if delta < 1:
        raise ValueError(f"delta must be >= 1, got {delta}")
    if len(P) <= delta:
        return np.zeros(0), np.zeros(0)
    return motion_magnitudes(relative_pose(P[:-delta], P[delta:]))
