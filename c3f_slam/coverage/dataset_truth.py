"""A data set's own coverage ground truth (C3VD's ``coverage_mesh.obj`` flags), kept by the
converter beside ``mesh.ply`` and reported by ``evaluate --gt`` next to our estimate and truth.

File ``SEQ/mesh_observed.txt`` (project layout): one line per triangle of ``SEQ/mesh.ply``,
in the same order, ``1`` = the data set marks the face observed in some frame, ``0`` = never
observed (C3VD: texture coordinate 1 = ``vt 0 0`` observed, 2 = ``vt 1 1`` not). The shares
are of triangle area (m^2): the area of never-observed faces over all faces whose centroid
lies on the wall of the explored segment (the truth's centreline, within ``max_radius``),
overall and per ``segment`` metres of that centreline.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import open3d as o3d

from c3f_core.atomic import atomic_write_text
from c3f_core.errors import InputError
from c3f_slam.coverage.centreline import Centreline

FLAGS_FILE = "mesh_observed.txt"


def write_observed_flags(path: str | Path, observed: np.ndarray) -> None:
    """Write per-triangle ``observed`` flags (bool (F,)) atomically, one ``0``/``1`` a line."""
    flags = np.asarray(observed, dtype=bool).reshape(-1)
    atomic_write_text(path, "".join("1\n" if f else "0\n" for f in flags))


def read_observed_flags(path: str | Path, n_triangles: int) -> np.ndarray:
    """Per-triangle flags from ``path``; InputError (one line naming the file) unless it holds
    exactly ``n_triangles`` lines of ``0`` or ``1``."""
    path = Path(path)
    try:
        lines = path.read_text().split()
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: cannot read observed flags ({exc})") from None
    bad = next((k for k, v in enumerate(lines) if v not in ("0", "1")), None)
    if bad is not None:
        raise InputError(f"{path}:{bad + 1}: observed flag must be 0 or 1, got {lines[bad][:20]!r}")
    if len(lines) != n_triangles:
        raise InputError(f"{path}: {len(lines)} observed flags for a mesh of {n_triangles} triangles")
    return np.asarray(lines) == "1"


def dataset_unseen(mesh: o3d.geometry.TriangleMesh, observed: np.ndarray, line: Centreline, segment: float,
                   max_radius: float) -> dict:
    """``{unseen_share, segments: [{start_m, end_m, unseen_share}]}`` of the flagged ``mesh``
    on the wall along ``line`` (shares 0..1; NaN where a segment holds no face)."""
    V = np.asarray(mesh.vertices, dtype=np.float64)
    tri = V[np.asarray(mesh.triangles, dtype=np.int64)]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    s, _, r, valid = line.locate(tri.mean(axis=1))
    valid &= r <= max_radius

    def share(rows: np.ndarray) -> float:
        a = area[rows]
        return float(a[~observed[rows]].sum() / a.sum()) if a.sum() > 0 else float("nan")

    segs = []
    for k in range(max(1, int(np.ceil(line.length / segment - 1e-9)))):
        start, end = k * segment, min((k + 1) * segment, line.length)
        segs.append({"start_m": start, "end_m": end, "unseen_share": share(valid & (s >= start) & (s < end))})
    return {"unseen_share": share(valid), "segments": segs, "faces": int(valid.sum())}
