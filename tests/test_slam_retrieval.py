"""Bounded per-keyframe work: keyframe candidate selection, incremental
components of the pose graph, windowed optimisation and the optimisation schedule."""

from __future__ import annotations

import numpy as np
import pytest

from c3f_slam import geometry as g
from c3f_slam.pipeline.frame_step import FrameInput
from c3f_slam.pipeline.retrieval import (
    AppearanceIndex,
    CandidateConfig,
    global_descriptor,
    select_candidates,
    spatial_neighbours,
)
from c3f_slam.posegraph import PoseGraph, information_from_points, transform_information
from tests.fake_places import PlaceWorld, keyframe_per_frame_slam, sift_like


def _contrafeat(rng: np.random.Generator, n: int = 60) -> np.ndarray:
    d = rng.normal(size=(n, 64))
    return (d / np.linalg.norm(d, axis=1, keepdims=True)).astype(np.float16)


# ---------------------------------------------------------------------- candidate selection


@pytest.mark.parametrize("make", [sift_like, _contrafeat], ids=["sift-uint8", "contrafeat-float16"])
def test_appearance_ranks_identical_keyframe_first(make):
    rng = np.random.default_rng(0)
    descs = [make(rng) for _ in range(200)]
    index = AppearanceIndex()
    for d in descs:
        index.add(global_descriptor(d))
    for target in (3, 77, 150):
        scores = index.scores(global_descriptor(descs[target]))
        assert scores.shape == (200,) and int(np.argmax(scores)) == target
        assert scores[target] == pytest.approx(1.0, abs=1e-4)
        # a perturbed copy (half the keypoints, shuffled) still ranks its keyframe first
        part = descs[target][rng.permutation(len(descs[target]))[:30]]
        assert int(np.argmax(index.scores(global_descriptor(part)))) == target
    g_ = global_descriptor(descs[0])
    assert g_.dtype == np.float32 and np.linalg.norm(g_) == pytest.approx(1.0, abs=1e-5)
    assert not global_descriptor(np.zeros((0, 128), np.uint8)).any()


def test_blocked_scores_equal_one_product(monkeypatch):
    """The scores are computed in row blocks (OpenBLAS threading, see retrieval._BLOCK): same numbers."""
    from c3f_slam.pipeline import retrieval

    rng = np.random.default_rng(7)
    index = AppearanceIndex()
    for _ in range(50):
        index.add(global_descriptor(_contrafeat(rng)))
    q = global_descriptor(_contrafeat(rng))
    whole = index.scores(q)
    monkeypatch.setattr(retrieval, "_BLOCK", 7)
    np.testing.assert_allclose(index.scores(q), whole, rtol=1e-5, atol=1e-6)


def test_selector_cap_recent_and_appearance():
    rng = np.random.default_rng(1)
    n, cfg = 300, CandidateConfig(max_candidates=12, recent=4, spatial=3, spatial_radius=0.02)
    index = AppearanceIndex()
    descs = [sift_like(rng) for _ in range(n)]
    for d in descs:
        index.add(global_descriptor(d))
    c = select_candidates(n, cfg, appearance=index.scores(global_descriptor(descs[42])))
    assert len(c.ids) == 12 and c.ids == sorted(set(c.ids))
    assert {296, 297, 298, 299} <= set(c.ids)  # the most recent ones, always
    assert 42 in c.ids and c.sources[42] == "appearance"
    assert (c.recent, c.spatial, c.appearance) == (4, 0, 8)
    # small maps: all keyframes (the paper's rule), and None = always all
    assert select_candidates(12, cfg).ids == list(range(12)) and select_candidates(12, cfg).all
    assert select_candidates(n, CandidateConfig(max_candidates=None)).ids == list(range(n))
    # never more than the cap, whatever the parts ask for
    tight = CandidateConfig(max_candidates=3, recent=4, spatial=8)
    c = select_candidates(n, tight, appearance=index.scores(global_descriptor(descs[42])), poses=np.tile(np.eye(4),
                                                                                                         (n, 1, 1)),
                          T_query=np.eye(4))
    assert c.ids == [297, 298, 299]


def test_spatial_neighbours_radius_direction_and_component():
    # keyframes on a line 5 mm apart, all looking along +z; keyframe 7 looks backwards
    poses = np.array([g.make_pose(np.eye(3), [0.005 * k, 0.0, 0.0]) for k in range(20)])
    poses[7] = g.make_pose(g.axis_angle_to_matrix([0.0, np.pi, 0.0]), [0.035, 0.0, 0.0])
    T = g.make_pose(np.eye(3), [0.036, 0.0, 0.0])
    near = spatial_neighbours(poses, T, radius=0.012, max_angle_deg=60.0, k=10)
    assert near == [8, 6, 9, 5]  # nearest first, 7 excluded by its viewing direction
    assert spatial_neighbours(poses, T, 0.012, 60.0, k=2) == [8, 6]
    assert spatial_neighbours(poses, T, 0.012, 60.0, k=10, accept=lambda v: v % 2 == 0) == [8, 6]
    assert spatial_neighbours(poses, T, 0.012, 60.0, k=10, exclude={8}) == [6, 9, 5]
    cfg = CandidateConfig(max_candidates=6, recent=2, spatial=3, spatial_radius=0.012)
    c = select_candidates(20, cfg, appearance=np.zeros(20), poses=poses, T_query=T)
    assert {k for k, src in c.sources.items() if src == "spatial"} == {6, 8, 9}
    assert {18, 19} <= set(c.ids) and len(c.ids) == 6 and c.appearance == 1


# ---------------------------------------------------------------------- pose graph bookkeeping


def _reference_components(pg: PoseGraph) -> dict[int, list[int]]:
    return {v: comp for comp in pg.components() for v in comp}


def _check_components(pg: PoseGraph) -> None:
    ref = _reference_components(pg)
    for v in range(pg.n_nodes):
        assert pg.component_nodes(v) == ref[v]
        assert pg.component_size(v) == len(ref[v]) and pg.component_oldest(v) == ref[v][0]
    main = pg.components()[0] if pg.n_nodes else []
    assert pg.main_component() == main  # largest, ties to the oldest
    assert all(pg.in_main(v) == (v in main) for v in range(pg.n_nodes))


def test_incremental_components_match_from_scratch_with_pruning():
    rng = np.random.default_rng(2)
    for _ in range(6):
        pg = PoseGraph()
        for step in range(120):
            if pg.n_nodes < 2 or rng.random() < 0.35:
                pg.add_node(np.eye(4))
            else:
                i, j = rng.choice(pg.n_nodes, 2, replace=False)
                pg.add_edge(int(i), int(j), np.eye(4), information=np.eye(6), uncertain=True)
            if step % 10 == 0:
                _check_components(pg)
            if step % 40 == 39 and pg.edges:  # prune some edges (what an optimisation does) and rebuild
                for k in rng.choice(len(pg.edges), max(1, len(pg.edges) // 3), replace=False):
                    pg.edges[int(k)].pruned = True
                pg.refresh_components()
                _check_components(pg)
        _check_components(pg)
    assert pg.components(include_pruned=True)[0] == sorted(pg.reachable([pg.components(True)[0][0]]))


def test_optimisation_pruning_updates_components():
    """Edges pruned by an optimisation leave the incremental components consistent with a
    from-scratch computation."""
    rng = np.random.default_rng(3)
    pts = rng.uniform(-0.02, 0.02, (80, 3)) + [0, 0, 0.03]
    pg = PoseGraph()
    gt = [g.make_pose(np.eye(3), [0.005 * k, 0, 0]) for k in range(6)]
    for T in gt:
        pg.add_node(T)
    for k in range(4):
        pg.add_edge(k, k + 1, g.relative_pose(gt[k], gt[k + 1]), points_j=pts)
    pg.add_edge(0, 2, g.relative_pose(gt[0], gt[2]), points_j=pts, uncertain=True)
    wrong = g.make_pose(g.axis_angle_to_matrix([0, 0.4, 0]), [0.03, 0, 0])
    pg.add_edge(1, 5, wrong, points_j=pts, uncertain=True)
    pg.add_edge(3, 5, g.relative_pose(gt[3], gt[5]), points_j=pts, uncertain=True)
    bad = pg.add_edge(4, 5, wrong, points_j=pts, uncertain=True)
    assert pg.component_size(0) == 6
    res = pg.optimize(reference_node=0)
    assert bad in res.pruned
    _check_components(pg)


def test_transform_information_equals_moved_points():
    rng = np.random.default_rng(4)
    p = rng.uniform(-0.02, 0.02, (50, 3)) + [0, 0, 0.03]
    T = g.make_pose(g.axis_angle_to_matrix([0.3, -0.2, 0.5]), [0.01, -0.04, 0.02])
    np.testing.assert_allclose(transform_information(information_from_points(p), T),
                               information_from_points(g.transform_points(T, p)), rtol=1e-9, atol=1e-12)


def test_windowed_optimisation_keeps_the_rest_fixed():
    """Exact edges, window nodes perturbed: a windowed optimisation recovers them and does not
    move any other node; edges into the window from both sides (free node as source and as
    target) are used."""
    rng = np.random.default_rng(5)
    pts = rng.uniform(-0.02, 0.02, (80, 3)) + [0, 0, 0.03]
    gt = [np.eye(4)]
    for _ in range(11):
        gt.append(gt[-1] @ g.make_pose(g.axis_angle_to_matrix(rng.normal(0, 0.05, 3)), [0.002, 0.001, 0.005]))
    pg = PoseGraph()
    for T in gt:
        pg.add_node(T)
    for k in range(11):
        pg.add_edge(k, k + 1, g.relative_pose(gt[k], gt[k + 1]), points_j=pts)
    for i, j in [(2, 6), (5, 9), (7, 11), (4, 7)]:
        pg.add_edge(i, j, g.relative_pose(gt[i], gt[j]), points_j=pts, uncertain=True)
    window = [5, 6, 7]
    for v in window:
        pg.set_pose(v, g.make_pose(g.axis_angle_to_matrix(rng.normal(0, 0.02, 3)), rng.normal(0, 0.003, 3)) @ gt[v])
    before = pg.poses
    res = pg.optimize(reference_node=0, nodes=window)
    assert res.optimized_nodes == window and res.fixed_nodes == [2, 4, 8, 9, 11]
    assert res.pruned == []
    after = pg.poses
    others = [v for v in range(12) if v not in window]
    np.testing.assert_array_equal(after[others], before[others])
    for v in window:
        np.testing.assert_allclose(after[v], gt[v], atol=1e-6)
    # the reference node stays fixed when it is inside a window
    pg.set_pose(1, g.make_pose(np.eye(3), [0.001, 0, 0]) @ gt[1])
    res = pg.optimize(reference_node=0, nodes=[0, 1, 2])
    assert res.optimized_nodes == [1, 2] and 0 in res.fixed_nodes
    np.testing.assert_array_equal(pg.pose(0), gt[0])
    np.testing.assert_allclose(pg.pose(1), gt[1], atol=1e-6)


# ---------------------------------------------------------------------- FragmentSlam with a fake matcher


def test_optimisation_schedule_small_then_geometric():
    world = PlaceWorld(60, reach=2)
    slam = keyframe_per_frame_slam(world, optimization={"small_map": 10, "growth": 0.5, "max_nodes": None,
                                                          "final_nodes": None})
    fired: list[int] = []
    inner = slam.map.schedule.optimize

    def spy(node, n_keyframes):
        fired.append(len(slam.map.keyframes))
        return inner(node, n_keyframes)

    slam.map.schedule.optimize = spy
    for k in range(60):
        slam.add(FrameInput(world.frame(k, k), np.zeros((4, 4))))
    # keyframe 2 (the 3rd) is the first with a loop (to 0); every loop keyframe optimises while
    # the map is small (< 10), then only once the keyframes added since the last optimisation
    # are 50 % of the component to optimise: 9 -> 18 -> 36 (geometric)
    assert fired == [3, 4, 5, 6, 7, 8, 9, 18, 36]
    n_before = slam.map.schedule.counts.optimizations
    slam.finish()
    assert slam.map.schedule.counts.optimizations == n_before + 1  # always at the end
    _, _, P, reg = slam.map.trajectory()
    assert reg.all()
    np.testing.assert_allclose(P[:, :3, 3], np.array(world.poses)[:, :3, 3], atol=1e-6)


def test_every_keyframe_switch_and_paper_rules():
    world = PlaceWorld(30, reach=2)
    slam = keyframe_per_frame_slam(world, optimization={"growth": None}, candidates={"max_candidates": None})
    for k in range(30):
        slam.add(FrameInput(world.frame(k, k), np.zeros((4, 4))))
    assert slam.map.schedule.counts.optimizations == 28  # every keyframe with a loop (keyframes 2..29)
    # all earlier keyframes but the link pair
    assert slam.placer.counts.candidates_matched == sum(max(k - 1, 0) for k in range(30))


def test_bounded_candidates_windows_and_relocalisation():
    """Many keyframes: at most the cap is matched per keyframe, optimisations stay within the
    window, the final sweep covers the map; after lost tracking, a keyframe of an old place
    is found by appearance alone (not recent, no pose estimate) and joins the map."""
    world = PlaceWorld(80, reach=2)
    slam = keyframe_per_frame_slam(world, candidates={"max_candidates": 6, "recent": 2, "spatial": 2},
                                   optimization={"small_map": 10, "growth": 0.1, "max_nodes": 12, "final_nodes": 30})
    sizes: list[int] = []
    inner = slam.map.graph.optimize

    def spy(*a, **k):
        res = inner(*a, **k)
        sizes.append(len(res.optimized_nodes))
        return res

    slam.map.graph.optimize = spy
    for k in range(70):
        before = slam.placer.counts.candidates_matched
        slam.add(FrameInput(world.frame(k, k), np.zeros((4, 4))))
        assert slam.placer.counts.candidates_matched - before <= 6
    assert max(sizes) <= 12 and slam.map.schedule.counts.windowed > 0
    # tracking lost; the camera is back at place 20 (50 places ago)
    slam.skip(70, 70 / 30.0)
    reloc = slam.placer.counts.relocalised
    slam.add(FrameInput(world.frame(71, 20), np.zeros((4, 4))))
    assert slam.placer.counts.relocalised == reloc + 1
    new = len(slam.map.keyframes) - 1
    assert any({e.i, e.j} == {20, new} for e in slam.map.graph.edges)
    assert slam.map.in_main(new)
    sizes.clear()
    slam.finish()
    assert len(sizes) > 1 and max(sizes) <= 12  # a sweep of windows (71 keyframes > 30)
    idx, _, P, reg = slam.map.trajectory()
    assert np.array_equal(reg, idx != 70)  # all but the skipped frame
    truth = np.array([world.poses[world.place[i]] for i in slam.map.log.index if i != 70])
    np.testing.assert_allclose(P[reg][:, :3, 3], truth[:, :3, 3], atol=1e-5)
    assert slam.stats()["keyframe_candidates_per_fragment"] <= 6
