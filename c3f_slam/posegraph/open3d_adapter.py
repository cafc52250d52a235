"""Open3D's registration pose graph and its solver (LM with line-process edge pruning).

Open3D 0.19 conventions (``pipelines/registration/GlobalOptimization.cpp``; pinned by
``tests/test_slam_posegraph.py::test_open3d_edge_convention``):

- ``PoseGraphNode.pose`` is the node's camera-to-world pose;
- ``PoseGraphEdge(s, t).transformation`` X is consistent when X = inv(pose_t) @ pose_s:
  it maps *source*-frame points into the *target* frame (X = T_ts in our naming). So our
  edge T_ij is stored as an Open3D edge with source = j, target = i;
- the residual and the information matrix act on *source*-frame points, ordered (rotation,
  translation) (:mod:`c3f_slam.posegraph.information`); entry (5, 5) of the information
  matrix is the number of correspondences, which Open3D uses for the line-process weight
  mu = preference_loop_closure * max_correspondence_distance^2 * mean(correspondences);
- uncertain edges get a line-process confidence l = (mu / (mu + e^T Lambda e))^2; those with
  l <= edge_prune_threshold are removed from the graph (two optimise/prune passes).
  Roughly: an uncertain edge is pruned when the RMS misalignment of its points after
  optimisation exceeds max_correspondence_distance * sqrt(preference_loop_closure)
  (times sqrt of mean/own correspondence count);
- ``global_optimization`` silently does nothing on a disconnected graph (the caller passes a
  connected one);
- Open3D's convergence thresholds are absolute (e.g. residual < 1e-6), so the caller gives
  lengths in units of ``max_correspondence_distance`` (see :mod:`c3f_slam.posegraph.optimize`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import open3d as o3d

from c3f_slam.posegraph.config import PoseGraphConfig

_reg = o3d.pipelines.registration


@dataclass(kw_only=True)
class Open3DProblem:
    """A pose graph in Open3D's terms, lengths in units of ``max_correspondence_distance``.

    ``node_poses``: camera-to-world pose per node; per edge n: ``source[n]`` / ``target[n]``
    (node indices), ``transformation[n]`` (4x4, maps source-frame points into the target
    frame), ``information[n]`` (6x6, rotation-translation order) and ``uncertain[n]``;
    ``reference_node``: the node Open3D holds fixed.
    """

    node_poses: list[np.ndarray]
    source: np.ndarray
    target: np.ndarray
    transformation: np.ndarray
    information: np.ndarray
    uncertain: list[bool]
    reference_node: int


@dataclass
class Open3DSolution:
    """``node_poses``: camera-to-world pose per node after optimisation (same units
    as the problem); ``edge_confidence``: per input edge Open3D's line-process value, None for
    the edges it removed."""

    node_poses: list[np.ndarray]
    edge_confidence: list[float | None]


def solve(problem: Open3DProblem, cfg: PoseGraphConfig) -> Open3DSolution:
    """Build Open3D's pose graph, run ``global_optimization`` (LM; not run without edges) with
    the pruning options of ``cfg`` and read the result back."""
    graph = _build(problem)
    if len(problem.uncertain):
        option = _reg.GlobalOptimizationOption(
            max_correspondence_distance=1.0,  # internal unit = max_correspondence_distance
            edge_prune_threshold=cfg.edge_prune_threshold,
            preference_loop_closure=cfg.preference_loop_closure,
            reference_node=problem.reference_node,
        )
        criteria = _reg.GlobalOptimizationConvergenceCriteria()
        criteria.max_iteration = int(cfg.max_iterations)
        with o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error):
            _reg.global_optimization(graph, _reg.GlobalOptimizationLevenbergMarquardt(), criteria, option)
    return Open3DSolution([np.asarray(node.pose) for node in graph.nodes], _kept_confidences(graph.edges, problem))


def _build(problem: Open3DProblem) -> _reg.PoseGraph:
    graph = _reg.PoseGraph()
    for T in problem.node_poses:
        graph.nodes.append(_reg.PoseGraphNode(T))
    src, tgt, X, L, unc = (problem.source, problem.target, problem.transformation, problem.information,
                           problem.uncertain)
    for n in range(len(unc)):
        graph.edges.append(_reg.PoseGraphEdge(int(src[n]), int(tgt[n]), X[n], L[n], uncertain=unc[n],
                                              confidence=1.0))
    return graph


def _kept_confidences(kept: _reg.PoseGraphEdgeVector, problem: Open3DProblem) -> list[float | None]:
    """Per input edge the confidence of its surviving Open3D edge, None when removed. Open3D
    keeps the surviving edges in their original order: with none removed they line up, else
    match them as a subsequence (source, target, transformation)."""
    n_edges, n_kept = len(problem.uncertain), len(kept)
    out: list[float | None] = []
    pos = 0
    for n in range(n_edges):
        if n_kept == n_edges or (pos < n_kept and _same_edge(kept[pos], int(problem.source[n]),
                                                             int(problem.target[n]), problem.transformation[n])):
            out.append(float(kept[pos].confidence))
            pos += 1
        else:
            out.append(None)
    if pos != n_kept:  # pragma: no cover - would mean Open3D reordered edges
        raise RuntimeError("could not match optimised edges to the input edges")
    return out


def _same_edge(edge: _reg.PoseGraphEdge, s: int, t: int, X: np.ndarray) -> bool:
    """True when the Open3D edge is the one built by :func:`solve` (source, target and the
    transformation, compared exactly)."""
    return (
        edge.source_node_id == s
        and edge.target_node_id == t
        and np.array_equal(np.asarray(edge.transformation), X)
    )
