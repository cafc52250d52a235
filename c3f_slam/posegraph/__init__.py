"""Pose-graph optimisation with line-process edge pruning (Choi et al. 2015) on Open3D.

One graph class serves both levels (docs/design.md, Pose graphs): the intra-fragment graph
(nodes = frames of a fragment, node 0 = its keyframe, poses relative to the keyframe) and the
global graph (nodes = keyframes, node 0 = the first keyframe). Conventions (see ``c3f_slam.geometry``): node poses
are camera-to-world ``T_wc`` (the "world" being the graph's reference frame); an edge
``(i, j, T_ij)`` says p_i = T_ij @ p_j, i.e. T_ij = inv(T_wi) @ T_wj. Metres and radians.

Parts:

- :mod:`~c3f_slam.posegraph.graph`: :class:`PoseGraph`, the facade composing the parts below;
- :mod:`~c3f_slam.posegraph.config`: one call's options (:class:`c3f_slam.config.PoseGraphConfig`);
- :mod:`~c3f_slam.posegraph.information`: information matrices and edge residuals;
- :mod:`~c3f_slam.posegraph.nodes`: the node poses in one growable (N, 4, 4) array;
- :mod:`~c3f_slam.posegraph.edges`: the edge storage (block rows, triangle storage),
  :class:`EdgeKind` and the :class:`Edge` / :class:`EdgeList` views;
- :mod:`~c3f_slam.posegraph.adjacency`: edges per node as linked lists through the edges;
- :mod:`~c3f_slam.posegraph.components`: union-find components, from-scratch components, walks;
- :mod:`~c3f_slam.posegraph.optimize`: the optimisation steps (window, problem, write-back) and
  :class:`OptimizationResult`;
- :mod:`~c3f_slam.posegraph.open3d_adapter`: Open3D's pose graph and solver, its conventions.
"""

from c3f_slam.config import PoseGraphConfig
from c3f_slam.posegraph.edges import Edge, EdgeKind, EdgeList
from c3f_slam.posegraph.graph import PoseGraph
from c3f_slam.posegraph.information import information_from_points, linearized_residual, transform_information
from c3f_slam.posegraph.optimize import OptimizationResult

__all__ = [
    "Edge",
    "EdgeKind",
    "EdgeList",
    "OptimizationResult",
    "PoseGraph",
    "PoseGraphConfig",
    "information_from_points",
    "linearized_residual",
    "transform_information",
]
