"""The layers of a view: geometry a page draws and a user switches on and off.

A :class:`Layer` is a triangle mesh (vertex colours), a polyline, line segments or points,
in the run's world frame (metres; the main map's, i.e. its first keyframe's camera frame).
:mod:`c3f_slam.view.scene` builds them from a run folder.
"""

from __future__ import annotations

import base64
from dataclasses import dataclass

import numpy as np
import open3d as o3d

from c3f_slam.view.budget import decimate


@dataclass
class Layer:
    """One switchable part of the view. ``kind``: ``mesh`` (``indices`` (T, 3), ``colours`` (N, 3)
    uint8 sRGB per vertex), ``line`` (a polyline through ``positions``), ``segments`` (pairs of
    ``positions``) or ``points``; ``colour`` (``#rrggbb``) draws lines and points; ``note`` says
    where the data came from and whether it was decimated."""

    id: str
    label: str
    kind: str
    positions: np.ndarray
    indices: np.ndarray | None = None
    colours: np.ndarray | None = None
    colour: str = "#ffffff"
    visible: bool = True
    note: str = ""

    @property
    def triangles(self) -> int:
        return 0 if self.indices is None else len(self.indices)

    def to_json(self) -> dict:
        """JSON-ready dict; arrays as base64 of little-endian float32 / uint32 / uint8."""
        d = {"id": self.id, "label": self.label, "kind": self.kind, "colour": self.colour, "visible": self.visible,
             "note": self.note, "positions": _b64(self.positions, "<f4")}
        if self.indices is not None:
            d["indices"] = _b64(self.indices, "<u4")
        if self.colours is not None:
            d["colours"] = _b64(self.colours, "u1")
        return d


def _b64(a: np.ndarray, dtype: str) -> str:
    return base64.b64encode(np.ascontiguousarray(a, dtype=dtype).tobytes()).decode("ascii")


def mesh_layer(lid: str, label: str, mesh: o3d.geometry.TriangleMesh, max_triangles: int, source: str,
               visible: bool = True) -> Layer:
    """A mesh layer of ``mesh`` decimated to ``max_triangles``; ``source`` names the full file."""
    full = len(mesh.triangles)
    small, cut = decimate(mesh, max_triangles)
    cols = np.asarray(small.vertex_colors) if small.has_vertex_colors() else np.full((len(small.vertices), 3), 0.7)
    note = (f"{len(small.triangles):,} of {full:,} triangles (decimated; full resolution: {source})" if cut
            else f"{full:,} triangles ({source})")
    return Layer(lid, label, "mesh", np.asarray(small.vertices), np.asarray(small.triangles),
                 np.round(np.clip(cols, 0, 1) * 255), visible=visible, note=note)


def triangles_coloured(mesh: o3d.geometry.TriangleMesh, colour, tol: float = 1.5 / 255) -> o3d.geometry.TriangleMesh:
    """The triangles of ``mesh`` whose three vertices all have ``colour`` (RGB in [0, 1])."""
    cols = np.asarray(mesh.vertex_colors)
    tris = np.asarray(mesh.triangles)
    if len(cols) == 0 or len(tris) == 0:
        return o3d.geometry.TriangleMesh()
    match = np.all(np.abs(cols - np.asarray(colour)) <= tol, axis=1)
    keep = tris[match[tris].all(axis=1)]
    out = o3d.geometry.TriangleMesh(mesh.vertices, o3d.utility.Vector3iVector(keep))
    out.vertex_colors = mesh.vertex_colors
    out.remove_unreferenced_vertices()
    return out


def frusta(poses: np.ndarray, K: np.ndarray, width: int, height: int, depth: float) -> np.ndarray:
    """(8 F x 2, 3) segment end points: each camera-to-world pose's viewing pyramid, ``depth``
    metres deep (apex to the four image corners, then the image rectangle)."""
    u = np.array([-0.5, width - 0.5, width - 0.5, -0.5])
    v = np.array([-0.5, -0.5, height - 0.5, height - 0.5])
    corners_c = np.stack([u, v, np.ones(4)], axis=1) @ np.linalg.inv(K).T * depth  # (4, 3) camera frame
    out = []
    for T in poses:
        apex, corners = T[:3, 3], corners_c @ T[:3, :3].T + T[:3, 3]
        for k in range(4):
            out += [apex, corners[k], corners[k], corners[(k + 1) % 4]]
    return np.asarray(out, dtype=np.float64).reshape(-1, 3)


def polyline_segments(paths: list[np.ndarray]) -> np.ndarray:
    """(2 S, 3) segment end points of several polylines (each (N, 3))."""
    segs = [np.stack([p[:-1], p[1:]], axis=1).reshape(-1, 3) for p in paths if len(p) >= 2]
    return np.concatenate(segs) if segs else np.zeros((0, 3))
