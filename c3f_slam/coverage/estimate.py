"""The share of the colon wall that no frame observed, per segment and overall.

:func:`compute_coverage` builds the centreline from the camera path, fits the wall model to
a surface (the run's fused mesh, or for the truth the true mesh) and tests each wall cell
against the frames (:mod:`.visibility`). Shares are of unrolled wall *area* (m^2: cell length x
angle x the ring's mean radius, :meth:`~c3f_slam.coverage.wall.WallModel.areas`) over the explored
segment (arc length 0 .. the farthest camera position); segments are ``segment`` metres of
centreline from the first camera position (the last one ends with the explored segment).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields

import numpy as np
import open3d as o3d

from c3f_slam.config import CoverageConfig
from c3f_slam.coverage.centreline import centreline_from_path
from c3f_slam.coverage.visibility import ViewSettings, observed, raycasting_scene, subsample_poses
from c3f_slam.coverage.wall import WallModel, fit_wall, surface_samples


class CoverageUnavailable(ValueError):
    """The run gives no basis for an estimate (too little camera motion, no surface)."""


@dataclass
class CoverageMap:
    """Per wall cell (S, A): ``observed`` and its ``area`` (m^2); the frames tested."""

    wall: WallModel
    observed: np.ndarray
    area: np.ndarray
    frames_used: int

    @property
    def length(self) -> float:
        return self.wall.centreline.length

    def unseen_share(self, rows: slice | np.ndarray = slice(None)) -> float:
        """Unseen share of the wall area of the cell rows ``rows`` (all: the explored segment)."""
        a = self.area[rows]
        return float(a[~self.observed[rows]].sum() / a.sum()) if a.sum() > 0 else float("nan")

    def segments(self, segment: float) -> list[dict]:
        """``{start_m, end_m, unseen_share, observed_share, area_m2, cells}`` per ``segment`` metres."""
        s = self.wall.s_centres
        out = []
        for k in range(max(1, int(np.ceil(self.length / segment - 1e-9)))):
            start, end = k * segment, min((k + 1) * segment, self.length)
            rows = (s >= start) & (s < end)
            if not rows.any():
                continue
            u = self.unseen_share(rows)
            out.append({"start_m": start, "end_m": end, "unseen_share": u, "observed_share": 1 - u,
                        "area_m2": float(self.area[rows].sum()), "cells": int(rows.sum() * self.area.shape[1])})
        return out

    def as_dict(self, segment: float) -> dict:
        """The quantities of coverage.json (shares in 0..1, lengths in metres)."""
        u = self.unseen_share()
        return {
            "unseen_share": u, "observed_share": 1 - u, "explored_length_m": self.length, "segment_m": segment,
            "segments": self.segments(segment),
            "wall_area_m2": float(self.area.sum()),
            "cells": {"along": int(self.area.shape[0]), "around": int(self.area.shape[1]),
                      "total": int(self.area.size), "observed": int(self.observed.sum()),
                      "unseen": int((~self.observed).sum()), "with_surface": int(self.wall.measured.sum())},
            "reconstructed_share": float(self.area[self.wall.measured].sum() / self.area.sum()),
            "frames_used": self.frames_used,
        }


def compute_coverage(surface: o3d.geometry.TriangleMesh, poses: np.ndarray, K: np.ndarray, view: ViewSettings,
                     cfg: CoverageConfig) -> CoverageMap:
    """Coverage of the wall modelled on ``surface`` (which also occludes) by the cameras at
    ``poses`` (camera-to-world (F, 4, 4), time order, NaN = unregistered) with intrinsics ``K``.
    Raises :class:`CoverageUnavailable`."""
    P = np.asarray(poses, dtype=np.float64).reshape(-1, 4, 4)
    line = centreline_from_path(P[:, :3, 3], cfg.node_spacing, cfg.smoothing, cfg.cell_length)
    if line is None:
        raise CoverageUnavailable(f"the camera moved less than {2 * cfg.node_spacing * 100:.1f} cm forward")
    if len(surface.triangles) == 0:
        raise CoverageUnavailable("the surface has no triangles")
    pts, colours = surface_samples(surface)
    wall = fit_wall(line, pts, colours=colours, cell_length=cfg.cell_length, angle_bins=cfg.angle_bins,
                    max_radius=cfg.max_radius, fill_gap=cfg.fill_gap)
    if wall is None:
        raise CoverageUnavailable(f"no surface within {cfg.max_radius * 100:.0f} cm of the camera path")
    frames = subsample_poses(P, cfg.max_frames)
    seen = observed(wall.probe_points().reshape(-1, 3), frames, K, view, raycasting_scene(surface)).reshape(wall.shape)
    if cfg.require_surface:
        seen &= wall.measured
    return CoverageMap(wall, seen, wall.areas(), len(frames))


def settings_dict(cfg: CoverageConfig, view: ViewSettings, K: np.ndarray) -> dict:
    """The settings recorded beside the shares (depth range resolved; ``K`` and ``image_size``
    of the images tested), enough to compute the truth the same way (:func:`settings_from_dict`)."""
    out = {**asdict(cfg), "depth_min": view.depth_min, "depth_max": view.depth_max,
           "image_size": [view.width, view.height], "K": np.asarray(K, dtype=np.float64).tolist()}
    if view.mask is not None:
        out["tissue_mask_share"] = float(view.mask.mean())
    return out


def settings_from_dict(d: dict, mask: np.ndarray | None = None) -> tuple[CoverageConfig, ViewSettings, np.ndarray]:
    """Inverse of :func:`settings_dict`; ``mask``: the observing pixels of the images tested
    (a run with a tissue mask records its share; :func:`c3f_slam.frames.tissue.coverage_grid_mask`)."""
    names = {f.name for f in fields(CoverageConfig)}
    cfg = CoverageConfig(**{k: v for k, v in d.items() if k in names})
    w, h = d["image_size"]
    view = ViewSettings(width=int(w), height=int(h), depth_min=float(d["depth_min"]),
                        depth_max=float(d["depth_max"]), tol=cfg.occlusion_tol,
                        tol_rel=cfg.occlusion_tol_rel, mask=mask)
    return cfg, view, np.asarray(d["K"], dtype=np.float64)
