"""TUM trajectory files: ``timestamp tx ty tz qx qy qz qw`` per line, camera-to-world."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from c3f_core.atomic import atomic_write_text
from c3f_core.errors import InputError
from c3f_slam.geometry import make_pose, matrix_to_quaternion, quaternion_to_matrix


def read_tum(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Read a TUM file; returns (timestamps (N,), camera-to-world poses (N, 4, 4)).

    Lines starting with ``#`` and blank lines are skipped.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: trajectory file not found")
    stamps, poses = [], []
    for lineno, line in enumerate(path.read_text().splitlines(), start=1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        parts = line.replace(",", " ").split()
        if len(parts) != 8:
            raise InputError(f"{path}:{lineno}: expected 8 numbers (t tx ty tz qx qy qz qw), got {len(parts)}")
        try:
            vals = np.array([float(p) for p in parts])
        except ValueError:
            raise InputError(f"{path}:{lineno}: not a number in {line!r}") from None
        if not np.all(np.isfinite(vals)):
            raise InputError(f"{path}:{lineno}: non-finite value")
        try:
            R = quaternion_to_matrix(vals[4:8])
        except ValueError:
            raise InputError(f"{path}:{lineno}: zero quaternion") from None
        stamps.append(vals[0])
        poses.append(make_pose(R, vals[1:4]))
    return np.asarray(stamps, dtype=np.float64), np.asarray(poses, dtype=np.float64).reshape(-1, 4, 4)


def format_tum(stamps: np.ndarray, poses: np.ndarray) -> str:
    lines = ["# timestamp tx ty tz qx qy qz qw (camera-to-world, metres)"]
    for t, T in zip(stamps, poses):
        q = matrix_to_quaternion(T[:3, :3])
        x, y, z = T[:3, 3]
        lines.append(f"{t:.6f} {x:.9f} {y:.9f} {z:.9f} {q[0]:.9f} {q[1]:.9f} {q[2]:.9f} {q[3]:.9f}")
    return "\n".join(lines) + "\n"


def write_tum(path: str | Path, stamps: np.ndarray, poses: np.ndarray) -> None:
    """Write camera-to-world poses to a TUM file atomically."""
    if len(stamps) != len(poses):
        raise ValueError(f"{len(stamps)} timestamps for {len(poses)} poses")
    atomic_write_text(path, format_tum(stamps, poses))
