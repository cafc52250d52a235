"""Pose graph: Open3D conventions, information matrix, edge pruning, drift correction."""

from __future__ import annotations

import numpy as np
import open3d as o3d
import pytest

from c3f_slam import geometry as g
from c3f_slam.config import PRESETS
from c3f_slam.posegraph import (
    EdgeKind,
    PoseGraph,
    PoseGraphConfig,
    information_from_points,
    linearized_residual,
)

reg = o3d.pipelines.registration


def _points(rng: np.random.Generator, n: int = 80) -> np.ndarray:
    """Colon-scale points in front of a camera (metres)."""
    return np.column_stack([rng.uniform(-0.02, 0.02, n), rng.uniform(-0.02, 0.02, n), rng.uniform(0.01, 0.05, n)])


def _perturb(T: np.ndarray, rng: np.random.Generator, t_sigma: float, r_sigma: float) -> np.ndarray:
    return T @ g.make_pose(g.axis_angle_to_matrix(rng.normal(0, r_sigma, 3)), rng.normal(0, t_sigma, 3))


def _chain(rng: np.random.Generator, n: int = 10) -> np.ndarray:
    """Ground-truth camera-to-world poses: 5 mm steps forward with small turns."""
    poses = [np.eye(4)]
    for _ in range(n - 1):
        step = g.make_pose(g.axis_angle_to_matrix(rng.normal(0, 0.05, 3)),
                           [rng.normal(0, 0.002), rng.normal(0, 0.002), 0.005])
        poses.append(poses[-1] @ step)
    return np.array(poses)


def _integrate(odometry: list[np.ndarray]) -> list[np.ndarray]:
    out = [np.eye(4)]
    for T in odometry:
        out.append(out[-1] @ T)
    return out


# ---------------------------------------------------------------------- conventions


def test_information_matches_open3d():
    """Our G^T G equals Open3D 0.19's get_information_matrix_from_point_clouds (identity transform)."""
    rng = np.random.default_rng(1)
    p = _points(rng, 50)
    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(p))
    theirs = reg.get_information_matrix_from_point_clouds(pc, pc, 1e-4, np.eye(4))
    ours = information_from_points(p)
    np.testing.assert_allclose(ours, theirs, rtol=1e-9, atol=1e-12)
    assert ours[5, 5] == pytest.approx(50)


def test_information_is_hessian_of_point_misalignment():
    """e^T Lambda e equals the summed squared misalignment of the frame-j points (small errors),
    and would not with the points taken in frame i: the source-frame choice matters."""
    rng = np.random.default_rng(2)
    T_wi = g.make_pose(g.axis_angle_to_matrix([0.1, -0.2, 0.3]), [0.01, 0.02, -0.03])
    T_ij = g.make_pose(g.axis_angle_to_matrix([0.3, 0.1, -0.2]), [0.04, -0.03, 0.05])
    T_wj_true = T_wi @ T_ij
    T_wj = _perturb(T_wj_true, rng, 1e-5, 1e-4)  # slightly wrong node pose
    p_j = _points(rng, 60)
    r = linearized_residual(T_ij, T_wi, T_wj)
    M = g.invert_pose(T_ij) @ g.invert_pose(T_wi) @ T_wj
    direct = np.sum((g.transform_points(M, p_j) - p_j) ** 2)
    ours = r @ information_from_points(p_j) @ r
    assert ours == pytest.approx(direct, rel=1e-3)
    wrong = r @ information_from_points(g.transform_points(T_ij, p_j)) @ r
    assert abs(wrong - direct) > 0.05 * direct


def test_open3d_edge_convention():
    """Raw Open3D: edge (s, t) with X is satisfied when X = inv(pose_t) @ pose_s (camera-to-world)."""
    X = g.make_pose(g.axis_angle_to_matrix([0.0, 0.3, 0.1]), [0.5, -0.2, 1.0])
    graph = reg.PoseGraph()
    graph.nodes.append(reg.PoseGraphNode(np.eye(4)))
    graph.nodes.append(reg.PoseGraphNode(g.make_pose(np.eye(3), [0.3, 0.0, 0.0])))  # wrong guess
    graph.edges.append(reg.PoseGraphEdge(0, 1, X, np.eye(6) * 100, uncertain=False))
    option = reg.GlobalOptimizationOption(max_correspondence_distance=0.05, reference_node=0)
    with o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error):
        reg.global_optimization(graph, reg.GlobalOptimizationLevenbergMarquardt(),
                                reg.GlobalOptimizationConvergenceCriteria(), option)
    P0, P1 = np.asarray(graph.nodes[0].pose), np.asarray(graph.nodes[1].pose)
    np.testing.assert_allclose(P0, np.eye(4), atol=1e-9)
    np.testing.assert_allclose(g.invert_pose(P1) @ P0, X, atol=1e-6)  # maps source 0 into target 1
    assert not np.allclose(g.invert_pose(P0) @ P1, X, atol=1e-3)


def test_wrapper_edge_means_T_ij():
    """Our add_edge(i, j, T_ij): after optimisation inv(T_wi) T_wj = T_ij and node 0 stays put."""
    rng = np.random.default_rng(3)
    T_01 = g.make_pose(g.axis_angle_to_matrix([0.05, -0.1, 0.2]), [0.004, 0.001, 0.006])
    pg = PoseGraph()
    pg.add_node(np.eye(4))
    pg.add_node(g.make_pose(np.eye(3), [0.01, 0.0, 0.0]))
    pg.add_edge(0, 1, T_01, points_j=_points(rng))
    res = pg.optimize(PoseGraphConfig())
    np.testing.assert_allclose(res.poses[0], np.eye(4), atol=1e-12)
    np.testing.assert_allclose(g.relative_pose(res.poses[0], res.poses[1]), T_01, atol=1e-6)
    assert res.pruned == [] and res.edge_rms[0] < 1e-5


# ---------------------------------------------------------------------- robustness


def _false_loop_graph(seed: int = 4):
    rng = np.random.default_rng(seed)
    gt = _chain(rng)
    odo = [_perturb(g.relative_pose(gt[k], gt[k + 1]), rng, 2e-4, 2e-3) for k in range(len(gt) - 1)]
    pg = PoseGraph()
    for P in _integrate(odo):
        pg.add_node(P)
    for k, T in enumerate(odo):
        pg.add_edge(k, k + 1, T, points_j=_points(rng))
    for i, j in [(0, 4), (2, 7), (3, 9), (5, 9)]:
        pg.add_edge(i, j, _perturb(g.relative_pose(gt[i], gt[j]), rng, 2e-4, 2e-3), points_j=_points(rng),
                    uncertain=True)
    wrong = g.relative_pose(gt[1], gt[8]) @ g.make_pose(g.axis_angle_to_matrix([0.0, 0.5, 0.0]), [0.03, 0.0, 0.01])
    bad = pg.add_edge(1, 8, wrong, points_j=_points(rng), uncertain=True)
    return pg, gt, bad


def test_prunes_planted_false_loop():
    pg, gt, bad = _false_loop_graph()
    before = np.linalg.norm(pg.poses[:, :3, 3] - gt[:, :3, 3], axis=1).max()
    res = pg.optimize(PRESETS["colon"].posegraph)
    assert res.pruned == [bad]
    assert pg.edges[bad].pruned and res.confidence[bad] == 0.0
    good_loops = [k for k, e in enumerate(pg.edges) if e.uncertain and k != bad]
    assert all(res.confidence[k] > 0.9 for k in good_loops)
    err = np.linalg.norm(res.poses[:, :3, 3] - gt[:, :3, 3], axis=1)
    assert err.max() < 1e-3 and err.max() < before  # within 1 mm of the truth
    assert res.edge_rms[bad] > 0.01  # the false loop really disagrees by centimetres
    assert res.component == list(range(10))


def test_false_loop_wins_without_pruning_power():
    """Control: with a huge loop preference the false edge is kept and distorts the poses."""
    pg, gt, bad = _false_loop_graph()
    res = pg.optimize(PRESETS["colon"].posegraph, preference_loop_closure=1e6)
    assert bad not in res.pruned
    err = np.linalg.norm(res.poses[:, :3, 3] - gt[:, :3, 3], axis=1)
    assert err.max() > 1e-3


def test_loop_closure_corrects_drift():
    """Biased odometry drifts; one correct loop closure pulls the chain back.

    Error = RMS displacement of scene points in front of each camera (what the pose graph
    minimises; camera centres alone are weakly tied to it through the ~3 cm lever arm).
    """
    rng = np.random.default_rng(5)
    gt = _chain(rng)
    bias = g.make_pose(g.axis_angle_to_matrix([0.0, 0.004, 0.0]), [0.0006, 0.0, 0.0])
    odo = [g.relative_pose(gt[k], gt[k + 1]) @ bias for k in range(len(gt) - 1)]
    pg = PoseGraph()
    for P in _integrate(odo):
        pg.add_node(P)
    for k, T in enumerate(odo):
        pg.add_edge(k, k + 1, T, points_j=_points(rng))
    pg.add_edge(0, 9, g.relative_pose(gt[0], gt[9]), points_j=_points(rng, 300), uncertain=True)
    scene = _points(np.random.default_rng(9), 200)

    def point_error(poses: np.ndarray) -> np.ndarray:
        return np.array([np.sqrt(np.mean(np.sum((g.transform_points(A, scene) - g.transform_points(B, scene)) ** 2, 1)))
                         for A, B in zip(poses, gt)])

    before = point_error(pg.poses)
    res = pg.optimize(PRESETS["colon"].posegraph)
    after = point_error(res.poses)
    assert res.pruned == [] and res.confidence[-1] > 0.9
    assert before[-1] > 5e-3  # 7 mm of drift at the end of the chain
    assert after[-1] < 0.1 * before[-1]
    assert np.sqrt(np.mean(after**2)) < 0.4 * np.sqrt(np.mean(before**2))


def test_scale_equivariance():
    """The same graph in room units (x100 lengths) gives the same answer scaled by 100."""
    pg, gt, bad = _false_loop_graph()
    big = PoseGraph()
    for P in pg.poses:
        big.add_node(np.block([[P[:3, :3], 100 * P[:3, 3:]], [np.zeros((1, 3)), np.ones((1, 1))]]))
    S = np.diag([100.0, 100.0, 100.0, 1.0, 1.0, 1.0])
    for e in pg.edges:
        T = e.T_ij.copy()
        T[:3, 3] *= 100
        big.add_edge(e.i, e.j, T, information=S @ e.information @ S, uncertain=e.uncertain)
    r_small = pg.optimize(PoseGraphConfig(max_correspondence_distance=0.003))
    r_big = big.optimize(PoseGraphConfig(max_correspondence_distance=0.3))
    assert r_small.pruned == r_big.pruned == [bad]
    np.testing.assert_allclose(r_big.poses[:, :3, 3], 100 * r_small.poses[:, :3, 3], atol=1e-6)


def test_other_components_untouched():
    """A lone node (candidate keyframe) keeps its pose and is reported outside the component."""
    rng = np.random.default_rng(6)
    pg = PoseGraph()
    pg.add_node(np.eye(4))
    pg.add_node(g.make_pose(np.eye(3), [0.01, 0, 0]))
    lone_pose = g.make_pose(g.axis_angle_to_matrix([0.1, 0, 0]), [0.5, 0.5, 0.5])
    pg.add_node(lone_pose)
    pg.add_edge(0, 1, g.make_pose(np.eye(3), [0.0, 0.0, 0.005]), points_j=_points(rng))
    res = pg.optimize()
    assert res.component == [0, 1] and res.optimized_nodes == [0, 1]
    np.testing.assert_array_equal(res.poses[2], lone_pose)
    np.testing.assert_allclose(res.poses[1][:3, 3], [0, 0, 0.005], atol=1e-6)
    assert pg.components() == [[0, 1], [2]]


def test_bad_edges_rejected():
    pg = PoseGraph()
    pg.add_node(np.eye(4))
    with pytest.raises(ValueError):
        pg.add_edge(0, 0, np.eye(4), information=np.eye(6))
    pg.add_node(np.eye(4))
    with pytest.raises(ValueError):
        pg.add_edge(0, 1, np.eye(4))  # neither points nor information
    with pytest.raises(ValueError):
        pg.add_edge(0, 1, np.full((4, 4), np.nan), information=np.eye(6))


def test_edge_kinds():
    """``kind`` takes an EdgeKind or its string and reads back as the plain string; other names are refused."""
    pg = PoseGraph()
    for _ in range(3):
        pg.add_node(np.eye(4))
    k = pg.add_edge(0, 1, np.eye(4), information=np.eye(6), uncertain=True, kind=EdgeKind.KEYFRAME)
    pg.add_edge(1, 2, np.eye(4), information=np.eye(6), kind="loop")
    assert pg.edges[k].kind == "keyframe" and type(pg.edges[k].kind) is str
    assert pg.kind_counts() == {"loop": 1, "keyframe": 1}
    with pytest.raises(ValueError, match="unknown edge kind 'relocalisation'"):
        pg.add_edge(0, 2, np.eye(4), information=np.eye(6), kind="relocalisation")
    assert pg.n_edges == 2
