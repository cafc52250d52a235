"""Memory of the SLAM runtime on long streams: compact pose-graph edge storage, the cap on
loop edges per keyframe, compact stored keyframes."""

from __future__ import annotations

import numpy as np
import open3d as o3d
import pytest

from c3f_core.errors import InputError
from c3f_slam import geometry as g
from c3f_slam.pipeline import SlamConfig
from c3f_slam.pipeline.frame_step import FrameInput
from c3f_slam.pipeline.frontend import PairMatch
from c3f_slam.pipeline.keyframe_edges import cap_keyframe_edges
from c3f_slam.pipeline.slam import FragmentSlam
from c3f_slam.posegraph import PoseGraph, PoseGraphConfig, information_from_points
from tests.fake_places import PlaceWorld, keyframe_per_frame_slam
from tests.test_slam_posegraph import _false_loop_graph

reg = o3d.pipelines.registration


# ---------------------------------------------------------------------- compact pose graph


def _open3d_reference(pg: PoseGraph, cfg: PoseGraphConfig) -> tuple[np.ndarray, list[int]]:
    """Whole-graph optimisation done directly with Open3D from the edges' values, with the
    wrapper's conventions (source = j, target = i; lengths in units of
    max_correspondence_distance): (camera-to-world poses (N, 4, 4) in metres, pruned edge ids)."""
    k = 1.0 / cfg.max_correspondence_distance
    graph = reg.PoseGraph()
    for P in pg.poses:
        Ps = P.copy()
        Ps[:3, 3] *= k
        graph.nodes.append(reg.PoseGraphNode(Ps))
    sc = np.array([k] * 3 + [1.0] * 3)
    for e in pg.edges:
        X = e.T_ij.copy()
        X[:3, 3] *= k
        graph.edges.append(reg.PoseGraphEdge(e.j, e.i, X, e.information * np.outer(sc, sc),
                                             uncertain=e.uncertain, confidence=1.0))
    option = reg.GlobalOptimizationOption(max_correspondence_distance=1.0,
                                          edge_prune_threshold=cfg.edge_prune_threshold,
                                          preference_loop_closure=cfg.preference_loop_closure, reference_node=0)
    criteria = reg.GlobalOptimizationConvergenceCriteria()
    criteria.max_iteration = int(cfg.max_iterations)
    with o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error):
        reg.global_optimization(graph, reg.GlobalOptimizationLevenbergMarquardt(), criteria, option)
    poses = np.array([np.asarray(n.pose) for n in graph.nodes])
    poses[:, :3, 3] *= 1.0 / k
    kept = {(int(e.source_node_id), int(e.target_node_id)) for e in graph.edges}
    pruned = [n for n, e in enumerate(pg.edges) if (e.j, e.i) not in kept]
    return poses, pruned


def test_compact_graph_equals_open3d_reference_bit_for_bit():
    """The planted false-loop graph: same optimised poses (bit for bit) and the same pruned
    edge as Open3D run directly on the edges' values."""
    pg, gt, bad = _false_loop_graph()
    cfg = PoseGraphConfig()
    ref_poses, ref_pruned = _open3d_reference(pg, cfg)
    res = pg.optimize(cfg)
    assert ref_pruned == res.pruned == [bad]
    assert pg.poses.tobytes() == ref_poses.tobytes()
    assert [e.pruned for e in pg.edges] == [n == bad for n in range(len(pg.edges))]
    assert pg.n_pruned() == 1 and res.confidence[bad] == 0.0


def test_multi_block_edge_storage_equals_open3d_reference():
    """More edges than one storage block (4,096): still the reference's poses, bit for bit."""
    rng = np.random.default_rng(5)
    gt = [g.make_pose(g.axis_angle_to_matrix([0.0, 0.01 * k, 0.0]), [0.004 * k, 0.0, 0.0]) for k in range(40)]
    pg = PoseGraph()
    for k, P in enumerate(gt):
        pg.add_node(P @ g.make_pose(np.eye(3), rng.normal(0, 3e-4, 3)) if k else P)
    info = information_from_points(rng.uniform(-0.01, 0.01, (40, 3)) + [0, 0, 0.03])
    for k in range(39):
        pg.add_edge(k, k + 1, g.relative_pose(gt[k], gt[k + 1]), information=info)
    for _ in range(4200):
        i, j = sorted(rng.choice(40, 2, replace=False).tolist())
        pg.add_edge(i, j, g.relative_pose(gt[i], gt[j]), information=info, uncertain=True)
    assert pg._edges.n_matrix_blocks == 2
    ref_poses, ref_pruned = _open3d_reference(pg, PoseGraphConfig(max_iterations=20))
    res = pg.optimize(PoseGraphConfig(max_iterations=20))
    assert res.pruned == ref_pruned == []
    assert pg.poses.tobytes() == ref_poses.tobytes()
    np.testing.assert_allclose(pg.poses[:, :3, 3], np.array(gt)[:, :3, 3], atol=1e-6)


def test_block_stored_appearance_index_scores(monkeypatch):
    """The appearance index in small storage blocks scores exactly like one block."""
    from c3f_slam.pipeline import retrieval
    from c3f_slam.pipeline.retrieval import AppearanceIndex, global_descriptor

    rng = np.random.default_rng(3)
    descs = [global_descriptor(rng.integers(0, 255, (30, 128)).astype(np.uint8)) for _ in range(70)]
    monkeypatch.setattr(retrieval, "_BLOCK", 16)
    whole = AppearanceIndex()
    for d in descs:
        whole.add(d)
    monkeypatch.setattr(retrieval, "_STORE_ROWS", 16)
    blocked = AppearanceIndex()
    for d in descs:
        blocked.add(d)
    assert len(blocked._rows.blocks) == 5 and blocked.nbytes == whole.nbytes == 70 * 128 * 4
    assert blocked.scores(descs[3]).tobytes() == whole.scores(descs[3]).tobytes()


def test_edge_views_return_stored_values_and_write_through():
    rng = np.random.default_rng(0)
    pg = PoseGraph()
    for _ in range(4):
        pg.add_node(np.eye(4))
    T = g.make_pose(g.axis_angle_to_matrix([0.1, 0.2, -0.3]), [0.001, 0.002, 0.003])
    pts = rng.uniform(-0.02, 0.02, (30, 3))
    info = information_from_points(pts)
    odd_T = T.copy()
    odd_T[3, 0] = 1e-9  # not rigid: kept whole
    odd_info = info.copy()
    odd_info[0, 1] += 1e-6  # not symmetric: kept whole
    k0 = pg.add_edge(0, 1, T, points_j=pts)
    k1 = pg.add_edge(1, 2, odd_T, information=odd_info, uncertain=True)
    k2 = pg.add_edge(0, 3, T, information=info, uncertain=True, kind="keyframe")
    for _ in range(40):  # grows the arrays past their initial capacity
        pg.add_edge(2, 3, T, information=info, uncertain=True)
    e0, e1, e2 = pg.edges[k0], pg.edges[k1], pg.edges[k2]
    assert (e0.i, e0.j, e0.kind, e0.uncertain, e0.pruned, e0.confidence) == (0, 1, "odometry", False, False, 1.0)
    assert e0.T_ij.tobytes() == T.tobytes() and e0.information.tobytes() == info.tobytes()
    assert e1.T_ij.tobytes() == odd_T.tobytes() and e1.information.tobytes() == odd_info.tobytes()
    assert e2.kind == "keyframe" and e2.n_correspondences == 30.0
    assert len(pg.edges) == pg.n_edges == 43 and pg.edges[-1].i == 2 and len(pg.edges[1:3]) == 2
    assert [e.j for e in pg.edges][:3] == [1, 2, 3]
    assert pg.kind_counts() == {"odometry": 1, "loop": 41, "keyframe": 1}
    assert pg.edges_of(0) == [k0, k2] and pg.edges_of(3)[0] == k2
    with pytest.raises(IndexError):
        pg.edges[43]
    # writes land in the graph: pruning by hand splits off node 3 after refresh_components
    pg.edges[k2].pruned = True
    for k in range(3, 43):
        pg.edges[k].pruned = True
    pg.edges[k1].confidence = 0.5
    pg.refresh_components()
    assert pg.n_pruned() == 41 and pg.edges[k1].confidence == 0.5
    assert pg.component_nodes(0) == [0, 1, 2] and pg.component_nodes(3) == [3]
    assert pg.components() == [[0, 1, 2], [3]]


# ---------------------------------------------------------------------- loop-edge cap


def _m(n: int) -> PairMatch:
    return PairMatch(np.eye(4), np.zeros((n, 3)), n)


def test_cap_keeps_most_recent_then_strongest():
    edges = [(9, _m(50), "odometry"), (8, _m(15), "keyframe")] + [(k, _m(20 + k), "loop") for k in range(8)]
    kept, dropped = cap_keyframe_edges(edges, 3)
    assert dropped == 6 and len(kept) == 4
    assert [k for k, _, kind in kept] == [9, 8, 6, 7]  # odometry, most recent (weakest), two strongest (input order)
    # one edge into another component survives even though it is weak
    comp = {k: (1 if k == 0 else 0) for k in range(10)}.__getitem__
    edges[2] = (0, _m(1), "loop")
    kept, _ = cap_keyframe_edges(edges, 3, comp)
    assert sorted(k for k, _, kind in kept if kind != "odometry") == [0, 7, 8]
    for cap in (None, 0, 9, 100):
        assert cap_keyframe_edges(edges, cap) == (edges, 0)


def _run(cap: int | None, n_frames: int = 60) -> tuple[FragmentSlam, PlaceWorld]:
    world = PlaceWorld(10, reach=3, seed=1, graded=True)
    slam = keyframe_per_frame_slam(world, candidates={"max_candidates": None}, keyframes={"max_loop_edges": cap})
    for k in range(n_frames):
        slam.add(FrameInput(world.frame(k, [*range(10), *range(8, 0, -1)][k % 18]), np.zeros((4, 4))))
    return slam, world


def _loop_edges_by_keyframe(slam: FragmentSlam) -> dict[int, list[int]]:
    out: dict[int, list[int]] = {}
    for e in slam.map.graph.edges:
        if e.uncertain:
            out.setdefault(max(e.i, e.j), []).append(min(e.i, e.j))
    return out


@pytest.mark.parametrize("cap", [2, 4])
def test_slam_keeps_at_most_cap_loop_edges_and_the_most_recent(cap):
    slam, world = _run(cap)
    full, _ = _run(None)
    capped, every = _loop_edges_by_keyframe(slam), _loop_edges_by_keyframe(full)
    assert max(len(v) for v in every.values()) > cap  # the cap does bite on this stream
    assert slam.placer.counts.edges_capped == sum(max(len(v) - cap, 0) for v in every.values()) > 0
    for node, olds in every.items():
        assert len(capped[node]) == min(len(olds), cap)
        assert max(olds) in capped[node]  # the most recent matched keyframe is kept
    assert slam.stats()["keyframe_matches_capped"] == slam.placer.counts.edges_capped
    # the map stays one piece and correct
    _, _, P, reg = slam.map.trajectory()
    assert reg.all()
    truth = np.array([world.poses[world.place[i]] for i in slam.map.log.index])
    np.testing.assert_allclose(P[:, :3, 3], truth[:, :3, 3], atol=1e-6)


def test_cap_none_or_zero_keeps_every_match():
    full, _ = _run(None, 40)
    zero, _ = _run(0, 40)
    assert full.placer.counts.edges_capped == zero.placer.counts.edges_capped == 0
    assert _loop_edges_by_keyframe(full) == _loop_edges_by_keyframe(zero)
    with pytest.raises(InputError, match="keyframes.max_loop_edges"):
        SlamConfig(keyframes={"max_loop_edges": -1})


# ---------------------------------------------------------------------- stored keyframes


def test_stored_keyframes_keep_only_what_matching_reads():
    slam, _ = _run(None, 5)
    kf = slam.map.keyframes[-1]
    assert kf.xy.shape == (0, 2) and len(kf) == 40
    assert kf.descriptors.dtype == np.uint8 and kf.points.dtype == np.float32
    assert kf.nbytes == 40 * (128 + 12)
    assert not hasattr(kf, "__dict__")  # slots: no per-keyframe attribute dict


def test_cli_loop_edge_cap_option(tiny_sequence, tmp_path, capsys):
    """--set keyframes.max_loop_edges=N sets the cap (none = keep all, as the paper's rules do);
    a negative value is one error line naming the setting."""
    import json

    from c3f_slam.cli.main import main

    for n, (args, expect) in enumerate(((["--set", "keyframes.max_loop_edges=3"], 3),
                                        (["--set", "keyframes.max_loop_edges=none"], None), ([], 8))):
        out = tmp_path / f"o{n}"
        assert main(["run", str(tiny_sequence), "--out", str(out), "--set", "frames.max_frames=4",
                     "--set", "fragments.min_correspondences=15", "--set", "fusion.enabled=false", "--quiet",
                     *args]) == 0
        assert json.loads((out / "summary.json").read_text())["config"]["keyframes"]["max_loop_edges"] == expect
    capsys.readouterr()
    bad = tmp_path / "bad"  # a bad setting: exit status 2, before the run folder
    assert main(["run", str(tiny_sequence), "--out", str(bad), "--set", "keyframes.max_loop_edges=-2", "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "keyframes.max_loop_edges" in err[0] and not bad.exists()


def test_block_rows_grow_and_read_back_exactly():
    from c3f_slam.posegraph.blocks import BlockRows

    rows = BlockRows((3,), np.float32, block_rows=8, capacity=2)
    data = np.random.default_rng(0).normal(size=(21, 3)).astype(np.float32)
    for k, v in enumerate(data):
        rows.ensure(k)
        rows.set(k, v)
    assert [len(b) for b in rows.blocks] == [8, 8, 8]  # 2 -> 4 -> 8, then whole blocks
    ids = np.array([20, 0, 9, 7, 16], np.int64)
    assert rows.take(ids).tobytes() == data[ids].tobytes()
    assert np.concatenate(list(rows.filled(21))).tobytes() == data.tobytes()
    with pytest.raises(ValueError, match="power of two"):
        BlockRows((3,), block_rows=6)
