"""Revisits hang off earlier keyframes (``SlamConfig.reuse_keyframes``): a stream that keeps
revisiting mapped places stops adding keyframes and edges, and the trajectory stays right."""

from __future__ import annotations

import numpy as np
import pytest

from c3f_slam.config import preset as slam_preset
from c3f_slam.pipeline import SlamConfig
from c3f_slam.pipeline.frame_step import FrameInput
from c3f_slam.pipeline.frontend import FrameFeatures, PairMatch
from c3f_slam.pipeline.slam import FragmentSlam
from tests.fake_places import PlaceWorld

#: pinhole camera of the fake frames: 32 x 32 px, f = 30 px (~56 deg field of view)
K = np.array([[30.0, 0.0, 16.0], [0.0, 30.0, 16.0], [0.0, 0.0, 1.0]])
#: a wall 3 cm in front of the camera (the fake world's points lie at ~3 cm)
DEPTH = np.full((32, 32), 0.03)


def _slam(world: PlaceWorld, reuse: bool, candidates: dict | None = None, skips_break: bool = False,
          **keyframes) -> FragmentSlam:
    """Graded matches (40 inliers at the same place, one fewer per place of distance) and 40
    consecutive correspondences needed to stay in a fragment: moving to another place opens
    a fragment, a frame at an already mapped place can continue that place's fragment.
    ``skips_break``: a skipped frame breaks the track (``rejoin.across_skipped`` false), so that
    ``skip`` stands for lost tracking."""
    cfg = slam_preset("colon", fragments={"min_correspondences": 40}, fusion={"enabled": False},
                                   keyframes={"reuse": reuse, **keyframes}, candidates=candidates or {},
                                   rejoin={"across_skipped": not skips_break})
    slam = FragmentSlam(cfg, K)
    world.use(slam)
    return slam


def _ping_pong(n_places: int, n_frames: int) -> list[int]:
    cycle = [*range(n_places), *range(n_places - 2, 0, -1)]
    return [cycle[k % len(cycle)] for k in range(n_frames)]


def _check_trajectory(slam: FragmentSlam, world: PlaceWorld, skipped: set[int] = frozenset()) -> None:
    idx, _, P, reg = slam.map.trajectory()
    assert np.array_equal(reg, [i not in skipped for i in idx])
    truth = np.array([world.poses[world.place[i]] for i in idx if i not in skipped])
    np.testing.assert_allclose(P[reg][:, :3, 3], truth[:, :3, 3], atol=1e-6)
    np.testing.assert_allclose(P[reg][:, :3, :3], truth[:, :3, :3], atol=1e-5)


def test_revisits_add_no_keyframes_and_no_edges():
    world = PlaceWorld(10, reach=3, seed=1, graded=True)
    slam, plain = _slam(world, True), _slam(world, False)
    places = _ping_pong(10, 60)
    edges_after_first_return = None
    decisions = []
    for k, p in enumerate(places):
        decisions.append(slam.add(FrameInput(world.frame(k, p), DEPTH)))
        plain.add(FrameInput(world.frame(k, p), DEPTH))
        if k == 11:
            edges_after_first_return = slam.map.graph.n_edges
    # every frame moves to another place: each opens a fragment, the first pass on new
    # keyframes (the first one lone), every later one attached to its place's keyframe
    assert [(d.index, d.fragment) for d in decisions] == [(k, k) for k in range(60)]
    assert [d.kind for d in decisions] == ["lone"] + ["keyframe"] * 9 + ["attached"] * 50
    assert decisions[0].reason == "first" and {d.reason for d in decisions[1:]} == {"correspondences"}
    assert all(d.opened and not d.rejoined for d in decisions)
    # the first pass makes the 10 keyframes; after it every fragment hangs off one of them
    assert len(slam.map.keyframes) == slam.map.graph.n_nodes == 10
    assert slam.map.counts.attached == slam.map.counts.fragments - 10 == 50
    # the first return closes one loop (the last new keyframe's link to its revisited
    # neighbour); from then on nothing is added
    assert slam.map.graph.n_edges == edges_after_first_return
    assert len(plain.map.keyframes) == 60 and plain.map.graph.n_edges > 3 * slam.map.graph.n_edges
    slam.finish()
    plain.finish()
    _check_trajectory(slam, world)
    _check_trajectory(plain, world)
    s = slam.stats()
    assert s["attached_fragments"] == 50 and s["fragments"] == 60 and s["keyframes"] == 10
    assert s["lone_fragments"] == 0 and plain.stats()["attached_fragments"] == 0
    # every frame is stored with the node it hangs off: the keyframe of its place
    nodes = np.asarray(slam.map.log.node)
    kf_place = [world.place[i] for i in slam.map.keyframes.frame_indices]
    assert [kf_place[n] for n in nodes] == places


def test_attach_needs_the_fragment_rules_overlap():
    """A frame whose matched keyframe sees too little of it (here: the frame looks away by
    90 degrees, its points outside the keyframe's view) makes a keyframe of its own."""
    world = PlaceWorld(4, reach=3, seed=2, graded=True)
    turned = world.poses[1] @ np.array([[0, 0, 1, 0], [0, 1, 0, 0], [-1, 0, 0, 0], [0, 0, 0, 1]], float)
    slam = _slam(world, True, skips_break=True)
    for k, p in enumerate([0, 1, 2]):
        slam.add(FrameInput(world.frame(k, p), DEPTH))
    # a frame at place 1, matched with the right relative pose but turned 90 deg
    feat = world.frame(3, 1)
    inner = world.match

    def match(a: FrameFeatures, b: FrameFeatures) -> tuple[PairMatch | None, int]:
        m, n = inner(a, b)
        if m is not None and b.index == 3:
            T = np.linalg.inv(world.poses[world.place[a.index]]) @ turned
            m = PairMatch(T, m.points_j, m.n)
        return m, n

    slam.match = match
    slam.add(FrameInput(feat, DEPTH))
    assert len(slam.map.keyframes) == 4 and slam.map.counts.attached == 0
    # and the same frame looking the right way hangs off keyframe 1
    slam.match = inner
    slam.skip(4, 4 / 30.0)
    slam.add(FrameInput(world.frame(5, 1), DEPTH))
    assert len(slam.map.keyframes) == 4 and slam.map.counts.attached == 1 and slam.map.frag_node[-1] == 1


def test_attached_revisit_merges_a_lone_component():
    """Places 0-3, lost tracking, places 4-7 (their matches to 0-3 hidden: a separate, lone
    component), then back over 6, 5, 4: the revisit of place 4 hangs off its keyframe and its
    match to place 3 (now visible) merges the two components without a new keyframe."""
    world = PlaceWorld(8, reach=1, seed=3, graded=True)
    slam = _slam(world, True, candidates={"max_candidates": None}, skips_break=True)
    hide = {"on": True}

    def match(a: FrameFeatures, b: FrameFeatures) -> tuple[PairMatch | None, int]:
        if hide["on"] and (world.place[a.index] < 4) != (world.place[b.index] < 4):
            return None, 0
        return world.match(a, b)

    slam.match = match
    for k, p in enumerate([0, 1, 2, 3]):
        slam.add(FrameInput(world.frame(k, p), DEPTH))
    slam.skip(4, 4 / 30.0)
    for k, p in zip(range(5, 9), [4, 5, 6, 7]):
        slam.add(FrameInput(world.frame(k, p), DEPTH))
    assert slam.map.graph.find(0) != slam.map.graph.find(7)  # two components
    hide["on"] = False
    for k, p in zip(range(9, 12), [6, 5, 4]):
        slam.add(FrameInput(world.frame(k, p), DEPTH))
    assert len(slam.map.keyframes) == 8 and slam.map.counts.attached == 3
    assert slam.map.graph.find(0) == slam.map.graph.find(7)
    slam.finish()
    # one map; the second component was moved rigidly into the first one's frame
    _check_trajectory(slam, world, skipped={4})


@pytest.mark.parametrize("reuse", [False, True])
def test_reuse_switch_in_config_and_cli(reuse, tiny_sequence, tmp_path):
    from c3f_slam.cli.main import main

    out = tmp_path / f"out_{reuse}"
    args = ["run", str(tiny_sequence), "--depth-source", "files", "--descriptors", "sift", "--out", str(out),
            "--set", "fusion.enabled=false", "--quiet", "--set", f"keyframes.reuse={str(reuse).lower()}"]
    assert main(args) == 0
    import json

    s = json.loads((out / "summary.json").read_text())
    assert s["config"]["keyframes"]["reuse"] is reuse
    assert s["keyframes"] + s["attached_fragments"] == s["fragments"]
    assert reuse or s["attached_fragments"] == 0
    graph = json.loads((out / "keyframe_graph.json").read_text())
    assert len(graph["nodes"]) == s["keyframes"]
    assert sorted({n["fragment"] for n in graph["nodes"]}) == sorted(n["fragment"] for n in graph["nodes"])


@pytest.mark.parametrize("check", [True, False])
def test_a_wrong_keyframe_match_does_not_attach_against_the_odometry(check):
    """Places 0-5 are mapped; a frame at the new place 6 (linked to place 5 by odometry)
    gets a wrong, strong match to keyframe 0 (identity pose, all points). It disagrees with
    the odometry by 3 cm, so the frame makes a keyframe of its own and the wrong edge is
    pruned by the optimisation; without the agreement check it would hang off keyframe 0 (where
    the host's match alone puts it: ``reuse_odometry_weight`` 0)."""
    world = PlaceWorld(8, reach=3, seed=4, graded=True)
    over = {} if check else dict(reuse_max_offset=1.0, reuse_max_angle_deg=180.0, reuse_odometry_weight=0.0)
    slam = _slam(world, True, **over)
    inner = world.match

    def match(a: FrameFeatures, b: FrameFeatures) -> tuple[PairMatch | None, int]:
        if world.place[a.index] == 0 and world.place[b.index] == 6:
            return PairMatch(np.eye(4), world.pts.astype(float), 40), 40
        return inner(a, b)

    slam.match = match
    for k in range(7):
        slam.add(FrameInput(world.frame(k, k), DEPTH))
    slam.finish()
    if check:
        assert len(slam.map.keyframes) == 7 and slam.map.counts.attached == 0
        assert slam.map.graph.n_pruned() >= 1
        _check_trajectory(slam, world)
    else:
        assert len(slam.map.keyframes) == 6 and slam.map.counts.attached == 1 and slam.map.frag_node[-1] == 0
        _, _, P, _ = slam.map.trajectory()
        np.testing.assert_allclose(P[-1], world.poses[0], atol=1e-9)  # the wrong pose


def test_reuse_options_are_checked():
    from c3f_core.errors import InputError

    with pytest.raises(InputError, match="reuse_max_offset"):
        SlamConfig(keyframes={"reuse_max_offset": -1.0})
    with pytest.raises(InputError, match="reuse_max_angle_deg"):
        SlamConfig(keyframes={"reuse_max_angle_deg": 200.0})
    assert slam_preset("room").keyframes.reuse_max_offset == 0.25
    from c3f_slam.pipeline import PAPER_RULES

    assert SlamConfig().keyframes.reuse and not SlamConfig(**PAPER_RULES).keyframes.reuse


def test_no_attach_to_the_keyframe_the_overlap_test_just_failed():
    """The fragment rule's overlap test also checks occlusions (the keyframe's depth); the
    reuse test cannot (keyframe depth is not kept). A frame that fails the former against the
    active keyframe (here: same place, but its depth disagrees with the keyframe's) must not
    hang off that very keyframe."""
    world = PlaceWorld(3, reach=2, seed=5, graded=True)
    slam = _slam(world, True, skips_break=True)
    slam.add(FrameInput(world.frame(0, 0), DEPTH))
    slam.add(FrameInput(world.frame(1, 0), DEPTH))  # appended to the keyframe's fragment
    slam.add(FrameInput(world.frame(2, 0), DEPTH * 2.0 / 3.0))
    assert slam.placer.counts.reasons["overlap"] == 1
    assert len(slam.map.keyframes) == 2 and slam.map.counts.attached == 0
    # the same frame after a gap (no overlap test against the active keyframe) does hang off it
    slam.skip(3, 3 / 30.0)
    slam.add(FrameInput(world.frame(4, 0), DEPTH * 2.0 / 3.0))
    assert len(slam.map.keyframes) == 2 and slam.map.counts.attached == 1 and slam.placer.counts.relocalised == 1


# ---------------------------------------------------------------------- end to end


def _ping_pong_sequence(src, dst, n):
    """``n`` frames of ``src`` played forward and backward (symbolic links, true poses)."""
    import os

    from c3f_slam.io import Sequence, write_tum

    seq = Sequence(src)
    order = _ping_pong(len(seq), n)
    (dst / "rgb").mkdir(parents=True)
    (dst / "depth").mkdir()
    for k, i in enumerate(order):
        os.symlink(seq.rgb_paths[i].resolve(), dst / "rgb" / f"{k:06d}.png")
        os.symlink(seq.depth_paths[i].resolve(), dst / "depth" / f"{k:06d}.png")
    write_tum(dst / "poses.txt", np.arange(n) / 30.0, seq.poses[order])
    (dst / "camera.json").write_text((src / "camera.json").read_text())
    return dst


@pytest.mark.e2e
def test_ping_pong_run_stops_adding_keyframes(tmp_path_factory):
    """RGB-D run over a 24-frame sequence played forward, back and forward again (70
    frames): with reuse the third pass adds no keyframe, the map has fewer keyframes and
    edges, and the trajectory is as accurate as without reuse."""
    import json

    from c3f_slam.pipeline import run_slam
    from c3f_slam.pipeline.run_evaluation import evaluate_run
    from datamodules.synthetic.fixture import make_tiny_sequence

    root = tmp_path_factory.mktemp("reuse")
    base = make_tiny_sequence(root / "base", frames=24, size=128, seed=5)
    seq = _ping_pong_sequence(base, root / "pp", 70)
    third_pass = 2 * 24 - 2  # first frame of the third pass
    res = {}
    for reuse in (True, False):
        cfg = slam_preset("colon", fragments={"min_correspondences": 15}, fusion={"enabled": False},
                                       keyframes={"reuse": reuse})
        s = run_slam(seq, root / f"out_{reuse}", cfg, progress=False)
        ev = evaluate_run(root / f"out_{reuse}", seq)
        graph = json.loads((root / f"out_{reuse}" / "keyframe_graph.json").read_text())
        res[reuse] = s, ev, [n["frame"] for n in graph["nodes"]]
        assert s["registered_share"] == 1.0
        assert ev["ate_se3"]["rmse_m"] < 0.005 * ev["gt_length_m"]
    (s, ev, frames), (s0, ev0, frames0) = res[True], res[False]
    assert s["attached_fragments"] > 0 and s["keyframes"] + s["attached_fragments"] == s["fragments"]
    assert max(frames) < third_pass <= max(frames0)
    assert s["keyframes"] < s0["keyframes"] and s["global_edges"] < s0["global_edges"]
    # as accurate as without reuse (here 0.18 mm either way; 25 % headroom for platform noise)
    assert ev["ate_se3"]["rmse_m"] <= 1.25 * ev0["ate_se3"]["rmse_m"]
