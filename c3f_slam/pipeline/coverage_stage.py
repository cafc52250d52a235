"""The run's last stage: the unseen-surface estimate (:mod:`c3f_slam.coverage`).

From the run's own outputs only (registered camera-to-world poses, the fused mesh) it writes
into the run folder, each file atomically:

- ``coverage.json``: ``unseen_share`` (0..1, overall over the explored segment),
  ``segments`` (``{start_m, end_m, unseen_share, ...}`` per ``coverage.segment`` metres),
  observed share, explored length, cell counts, the settings;
- ``coverage_map.png``: the unrolled wall, unseen cells flagged;
- ``unseen.ply``: the fused mesh with the unseen wall added as painted patches.

A run without a mesh (``--set fusion.enabled=false``), or with too little forward motion for
a centreline, gets ``coverage.json`` with ``status`` and the reason and no map;
``--set coverage.enabled=false`` writes nothing. The stage never fails the run: an unexpected
error is recorded in summary.json.
"""

from __future__ import annotations

import time

import numpy as np
from open3d.geometry import TriangleMesh

from c3f_slam.camera.intrinsics import PinholeCamera
from c3f_slam.config import SlamConfig
from c3f_slam.coverage import (
    CoverageConfig,
    CoverageMap,
    CoverageUnavailable,
    ViewSettings,
    compute_coverage,
    settings_dict,
)
from c3f_slam.coverage.render import draw_coverage_map, unseen_mesh
from c3f_slam.frames.tissue import TissueMask
from c3f_slam.fusion.tsdf import write_mesh
from c3f_slam.io.run_outputs import RunOutputs, write_json
from c3f_slam.pipeline.backend import SlamMap
from c3f_slam.pipeline.frontend import ModelDepth
from c3f_slam.pipeline.sources import RunSources


def fusion_camera(sources: RunSources) -> PinholeCamera:
    """The camera of the images fusion integrates: the network grid with model depth, else the frames'."""
    return sources.depth.view.camera if isinstance(sources.depth, ModelDepth) else sources.camera


def fusion_mask(sources: RunSources) -> np.ndarray | None:
    """The tissue area on the grid of the images fusion integrates (None: every pixel)."""
    if isinstance(sources.depth, ModelDepth):
        return sources.depth.network_tissue
    return None if sources.tissue.whole_frame else sources.tissue.pixels


def view_settings(camera: PinholeCamera, cfg: SlamConfig, mask: np.ndarray | None = None) -> ViewSettings:
    """Image size, the depth range fusion integrates (or coverage's own), the occlusion tolerance
    and the pixels that observe (``mask``, the tissue area; None: all)."""
    c, t = cfg.coverage, cfg.fusion.tsdf
    near, far = c.depth_range(t.depth_min, t.depth_max)
    return ViewSettings(width=camera.width, height=camera.height, depth_min=near, depth_max=far, tol=c.occlusion_tol,
                        tol_rel=c.occlusion_tol_rel, mask=mask)


def coverage_report(cov: CoverageMap, cfg: CoverageConfig, view: ViewSettings, K: np.ndarray) -> dict:
    """coverage.json's content for a computed :class:`~c3f_slam.coverage.CoverageMap`."""
    return {"status": "ok", **cov.as_dict(cfg.segment), "settings": settings_dict(cfg, view, K),
            "convention": "shares of wall area (0..1); arc length s in metres from the first registered camera "
                          "position to the farthest one along the centreline of the camera path"}


def write_coverage(outputs: RunOutputs, mesh: TriangleMesh | None, poses: np.ndarray, camera: PinholeCamera,
                   cfg: SlamConfig, *, mask: np.ndarray | None = None) -> dict:
    """Estimate and write the coverage outputs; returns summary.json's fields (``unseen_share``,
    ``coverage``: status and files). ``poses``: camera-to-world (F, 4, 4) in time order, NaN
    where unregistered; ``mask``: the tissue area of ``camera``'s images (written as
    ``coverage_mask.png`` for the evaluation against the truth)."""
    c = cfg.coverage
    if not c.enabled:
        return {"coverage": {"status": "off"}}
    view = view_settings(camera, cfg, mask)
    if mask is not None:
        TissueMask(mask, "fusion grid").write_png(outputs.coverage_mask)
    try:
        if mesh is None:
            raise CoverageUnavailable("no mesh (fusion.enabled=false)")
        cov = compute_coverage(mesh, poses, camera.K, view, c)
    except CoverageUnavailable as exc:
        write_json(outputs.coverage_json, {"status": "unavailable", "reason": str(exc), "unseen_share": None,
                                           "segments": [], "settings": settings_dict(c, view, camera.K)})
        return {"unseen_share": None, "coverage": {"status": "unavailable", "reason": str(exc)}}
    report = coverage_report(cov, c, view, camera.K)
    write_json(outputs.coverage_json, report)
    draw_coverage_map(outputs.coverage_png, cov, c.segment)
    write_mesh(unseen_mesh(mesh, cov), outputs.unseen_mesh)
    files = [p.name for p in (outputs.coverage_json, outputs.coverage_png, outputs.unseen_mesh)]
    return {"unseen_share": report["unseen_share"], "coverage": {"status": "ok", "files": files}}


def run_coverage(outputs: RunOutputs, mesh: TriangleMesh | None, slam_map: SlamMap, sources: RunSources,
                 cfg: SlamConfig) -> dict:
    """:func:`write_coverage` for a finished run (the registered trajectory of its back-end's
    map); an unexpected error is returned as ``coverage.status`` ``error`` instead of failing the run."""
    t0 = time.perf_counter()
    try:
        _, _, poses, registered = slam_map.trajectory()
        poses = np.where(np.asarray(registered, bool)[:, None, None], poses, np.nan)
        out = write_coverage(outputs, mesh, poses, fusion_camera(sources), cfg, mask=fusion_mask(sources))
    except Exception as exc:  # the run's own outputs stay valid
        out = {"unseen_share": None, "coverage": {"status": "error", "error": f"{type(exc).__name__}: {exc}"}}
    out["coverage"]["seconds"] = time.perf_counter() - t0
    return out
