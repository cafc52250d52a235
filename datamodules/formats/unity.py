"""Unity's left-handed frame (UTS-synthetic, SimCol3D) and the project's right-handed one.

Unity: x right, y up, z forward (left-handed). The project (OpenCV): x right, y down,
z forward. Both data sets' own code converts with ``F = diag(1, -1, 1)``: a camera-to-world
pose (R_u, t_u) read in Unity becomes ``R = F R_u F``, ``t = F t_u`` (SimCol3D's
``TM @ P @ TM``; UTS's README flips y and maps the quaternion (qx, qy, qz, qw) to
(-qx, qy, -qz, qw), which is the same matrix). Translations are in centimetres in both
releases.
"""

from __future__ import annotations

import numpy as np

from c3f_slam.geometry import make_pose, matrix_to_quaternion, quaternion_to_matrix

FLIP_Y = np.diag([1.0, -1.0, 1.0])
CM = 0.01  # metres per centimetre


def pose_from_unity(t_cm: np.ndarray, q_xyzw: np.ndarray) -> np.ndarray:
    """Unity camera-to-world (translation in cm, quaternion qx qy qz qw) -> ours (4x4, metres)."""
    R = FLIP_Y @ quaternion_to_matrix(np.asarray(q_xyzw, dtype=np.float64)) @ FLIP_Y
    return make_pose(R, FLIP_Y @ np.asarray(t_cm, dtype=np.float64) * CM)


def pose_to_unity(T_wc: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Our camera-to-world pose -> (translation in cm, quaternion qx qy qz qw) in Unity's frame."""
    R = FLIP_Y @ T_wc[:3, :3] @ FLIP_Y
    return FLIP_Y @ T_wc[:3, 3] / CM, matrix_to_quaternion(R)
