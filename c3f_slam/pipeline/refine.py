"""Dense refinement of keyframe-to-keyframe edges: Open3D's coloured ICP (Park et
al. 2017), multi-scale, started from the sparse estimate.

Each new keyframe's RGB-D frame becomes a coloured point cloud (grey as colour, every
``stride``-th pixel, metres, camera frame) per voxel size of :class:`RefineConfig`; the
clouds of the last ``cache`` keyframes are kept. An edge (k, T_k,new) of the new keyframe to
a cached keyframe k is refined by ICP of the new cloud (source) onto k's (target), coarse to
fine, and **verified** on the finest clouds: the refined pose must stay within
``max_correction`` (metres) / ``max_correction_deg`` of the sparse pose, reach ``min_fitness``,
raise the fitness by ``min_gain`` over the sparse pose (else the sparse edge, whose many
averaged matches are often as accurate as ICP on noisy depth, is kept) and not fit worse
(fitness not lower by over 0.01; inlier RMSE not over 5 % higher unless the fitness rose).
An accepted edge carries Open3D's information matrix of the refined alignment
(``get_information_matrix_from_point_clouds``), so the pose graph weights it by its dense
correspondences; a rejected one keeps its sparse transform and points.

Transforms follow :mod:`c3f_slam.posegraph`: T_k,new maps new-frame points into keyframe k.
"""

from __future__ import annotations

from collections import Counter, OrderedDict
from typing import NamedTuple

import numpy as np
import open3d as o3d

from c3f_slam.config import RefineConfig
from c3f_slam.geometry import backproject_pixels, invert_pose, motion_magnitudes
from c3f_slam.pipeline.fallback import RgbdFrame
from c3f_slam.posegraph import EdgeKind

#: the kinds of keyframe edges that are refined (a fallback edge is dense already)
REFINED_KINDS = (EdgeKind.ODOMETRY, EdgeKind.KEYFRAME, EdgeKind.LOOP)
#: tolerances of the "not worse" test: fitness may drop this much, inlier RMSE grow by this factor
FITNESS_TOLERANCE, RMSE_TOLERANCE = 0.01, 1.05

Pyramid = list  # one o3d.geometry.PointCloud (with normals) per voxel size, coarse to fine


class Refinement(NamedTuple):
    """An accepted refinement: T_k,new (metres) and its 6x6 information (Open3D order)."""

    T: np.ndarray
    information: np.ndarray


def cloud_pyramid(frame: RgbdFrame, K: np.ndarray, cfg: RefineConfig) -> Pyramid | None:
    """The frame's coloured cloud (camera frame, metres) at each voxel size, with normals;
    None when a level has too few points for ICP."""
    h, w = frame.depth.shape
    v, u = np.mgrid[0:h:cfg.stride, 0:w:cfg.stride]
    z = frame.depth[v, u]
    ok = z > 0
    if ok.sum() < 50:
        return None
    pts = backproject_pixels(np.stack([u[ok], v[ok]], axis=1), z[ok], K)
    grey = np.repeat(frame.gray[v[ok], u[ok]].astype(np.float64)[:, None], 3, axis=1)
    base = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts.astype(np.float64)))
    base.colors = o3d.utility.Vector3dVector(grey)
    levels = []
    for voxel in cfg.voxels:
        pc = base.voxel_down_sample(voxel)
        if len(pc.points) < 30:
            return None
        pc.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=2 * voxel, max_nn=30))
        levels.append(pc)
    return levels


class EdgeRefiner:
    """Keeps the clouds of recent keyframes and refines the edges of a new one (see the module notes)."""

    def __init__(self, cfg: RefineConfig, K: np.ndarray) -> None:
        self.cfg = cfg
        self.K = np.asarray(K, dtype=np.float64)
        self.clouds: OrderedDict[int, Pyramid] = OrderedDict()
        self.current: Pyramid | None = None
        self.outcomes: Counter[str] = Counter()

    def observe(self, rgb: np.ndarray | None, depth: np.ndarray) -> None:
        """The frame about to become a keyframe (``rgb`` (H, W, 3) uint8, depth metres)."""
        self.current = None if rgb is None else cloud_pyramid(RgbdFrame.from_rgb(rgb, depth), self.K, self.cfg)

    def keep(self, node: int) -> None:
        """The observed frame became keyframe ``node``: keep its clouds (drop the oldest beyond ``cache``)."""
        if self.current is None:
            return
        self.clouds[node] = self.current
        while len(self.clouds) > self.cfg.cache:
            self.clouds.popitem(last=False)

    def refine_edges(self, edges: list) -> dict[int, Refinement]:
        """Refinements of ``edges`` (:class:`~c3f_slam.pipeline.keyframe_edges.KeyframeEdge`)
        of the observed frame, by edge index: at most ``max_edges`` (odometry first, then the
        strongest), only to cached keyframes."""
        if self.current is None:
            return {}
        order = sorted((n for n, e in enumerate(edges) if e.kind in REFINED_KINDS and e.k in self.clouds),
                       key=lambda n: (edges[n].kind != EdgeKind.ODOMETRY, -edges[n].match.n))
        out = {}
        for n in order[:self.cfg.max_edges]:
            r = self.refine(self.clouds[edges[n].k], self.current, edges[n].match.T_ij)
            if r is not None:
                out[n] = r
        return out

    def refine(self, target: Pyramid, source: Pyramid, T_sparse: np.ndarray) -> Refinement | None:
        """Coloured ICP of ``source`` onto ``target`` from ``T_sparse`` (target <- source),
        verified; None (and the reason counted) when rejected."""
        T = np.asarray(T_sparse, dtype=np.float64)
        try:
            for voxel, iters, src, dst in zip(self.cfg.voxels, self.cfg.iterations, source, target, strict=True):
                res = o3d.pipelines.registration.registration_colored_icp(
                    src, dst, 1.5 * voxel, T, o3d.pipelines.registration.TransformationEstimationForColoredICP(),
                    o3d.pipelines.registration.ICPConvergenceCriteria(1e-6, 1e-6, iters))
                T = np.asarray(res.transformation, dtype=np.float64)
        except RuntimeError:  # too few correspondences at some level
            self.outcomes["no_convergence"] += 1
            return None
        why = self.failure(target[-1], source[-1], T_sparse, T)
        self.outcomes[why or "accepted"] += 1
        if why is not None:
            return None
        info = o3d.pipelines.registration.get_information_matrix_from_point_clouds(
            source[-1], target[-1], 1.5 * self.cfg.voxels[-1], T)
        return Refinement(T, np.asarray(info, dtype=np.float64))

    def failure(self, target, source, T_sparse: np.ndarray, T: np.ndarray) -> str | None:
        """Why the refined ``T`` is rejected (None: accepted); residuals on the finest clouds."""
        if not np.all(np.isfinite(T)):
            return "no_convergence"
        step, turn = (float(x[0]) for x in motion_magnitudes((invert_pose(T_sparse) @ T)[None]))
        if step > self.cfg.max_correction or turn > self.cfg.max_correction_deg:
            return "large_correction"
        dist = 1.5 * self.cfg.voxels[-1]
        before = o3d.pipelines.registration.evaluate_registration(source, target, dist, T_sparse)
        after = o3d.pipelines.registration.evaluate_registration(source, target, dist, T)
        if after.fitness < self.cfg.min_fitness:
            return "low_fitness"
        if after.fitness < before.fitness + self.cfg.min_gain:  # the sparse edge fits as well: keep it
            return "no_gain"
        if after.fitness < before.fitness - FITNESS_TOLERANCE or (
                after.inlier_rmse > RMSE_TOLERANCE * before.inlier_rmse and after.fitness <= before.fitness):
            return "worse_residual"
        return None

    def stats(self) -> dict:
        """Counters for summary.json: attempts and their outcomes."""
        return {"refine_attempts": int(sum(self.outcomes.values())), "refine_accepted": self.outcomes["accepted"],
                "refine_outcomes": dict(sorted(self.outcomes.items()))}
