"""Output of what could not be joined: the main map is the component with the most
frames; every other component with enough frames gets its own trajectory and mesh in
OUT/components/NN/, summary.json lists them all, and evaluate reports each one's ATE.

That a lone component which revisits the map merges into it (and so is not left as a
component) is tested in tests/test_slam_rejoin.py
(``test_frames_after_a_break_rejoin_the_map_at_the_right_place``); here only that the merged
map is then listed as one component.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from c3f_slam import geometry as g
from c3f_slam.cli.main import main
from c3f_slam.config import ComponentConfig
from c3f_slam.config import preset as slam_preset
from c3f_slam.io import Sequence, SequenceWriter, read_tum
from c3f_slam.io.run_outputs import RunOutputs
from c3f_slam.pipeline import SlamConfig, run_slam
from c3f_slam.pipeline.components import MapComponent, plan_components
from c3f_slam.pipeline.frame_step import FrameInput
from c3f_slam.pipeline.run_evaluation import evaluate_run, format_report
from c3f_slam.pipeline.slam import FragmentSlam
from datamodules.synthetic.fixture import make_tiny_sequence
from tests.fake_places import PlaceWorld

FRAMES_A, FRAMES_B = 40, 32  #: the two unrelated scenes of the unjoinable stream


@pytest.fixture(scope="module")
def two_scenes(tmp_path_factory) -> Path:
    """Two simulator sequences (different seeds: different colons) back to back in one
    sequence folder; the ground truth keeps each scene's poses (two unrelated worlds)."""
    root = tmp_path_factory.mktemp("components")
    a = Sequence(make_tiny_sequence(root / "a", frames=FRAMES_A, size=128, seed=3))
    b = Sequence(make_tiny_sequence(root / "b", frames=FRAMES_B, size=128, seed=11))
    w = SequenceWriter(root / "ab", a.camera)
    for k, (seq, i) in enumerate([(a, i) for i in range(len(a))] + [(b, i) for i in range(len(b))]):
        w.write_frame(k, seq.read_rgb(i), seq.read_depth(i))
    dt = float(a.timestamps[1] - a.timestamps[0])
    w.finish(np.concatenate([a.poses, b.poses]), dt * np.arange(len(a) + len(b)))
    return root / "ab"


@pytest.fixture(scope="module")
def run_out(two_scenes, tmp_path_factory) -> tuple[Path, dict]:
    """A run at default settings (fusion on) on the unjoinable stream."""
    out = tmp_path_factory.mktemp("components_run") / "out"
    return out, run_slam(two_scenes, out, SlamConfig(), progress=False)


@pytest.mark.e2e
def test_unjoinable_stream_writes_both_components(run_out):
    out, s = run_out
    comps = s["components"]
    assert [c["id"] for c in comps] == [0, 1] and comps[0]["main"] and not comps[1]["main"]
    assert sum(c["frames"] for c in comps) == s["processed"] == FRAMES_A + FRAMES_B
    main, other = comps
    assert (main["frames"], main["first_frame"], main["last_frame"]) == (FRAMES_A, 0, FRAMES_A - 1)
    assert (other["frames"], other["first_frame"], other["last_frame"]) == (FRAMES_B, FRAMES_A,
                                                                            FRAMES_A + FRAMES_B - 1)
    assert main["files"] == ["trajectory.txt", "mesh.ply"] and main["not_written"] is None
    assert other["files"] == ["components/01/trajectory.txt", "components/01/mesh.ply"]
    assert other["keyframes"] >= 1 and 0.05 < other["path_length_m"] < 0.2  # the simulator: ~4 mm per frame
    stamps, _ = read_tum(out / "components/01/trajectory.txt")
    assert len(stamps) == FRAMES_B and len(read_tum(out / "trajectory.txt")[0]) == FRAMES_A
    assert (out / "components/01/mesh.ply").stat().st_size > 1000
    assert s["registered_frames"] == FRAMES_A  # the main map is the scene with more frames
    assert not list(out.parent.glob(".out.partial*"))  # built in one staging folder, moved into place


def test_evaluate_reports_the_ate_of_each_component(run_out, two_scenes):
    out, _ = run_out
    res = evaluate_run(out, two_scenes)
    rows = {c["id"]: c for c in res["components"]}
    assert set(rows) == {0, 1} and rows[0]["main"] and rows[1]["trajectory"] == "components/01/trajectory.txt"
    assert (rows[0]["frames"], rows[1]["frames"]) == (FRAMES_A, FRAMES_B)
    for c in rows.values():  # each scene aligned on its own: both accurate (measured: about 0.3 %)
        assert c["n_associated"] == c["frames"] and c["ate_share_of_length"] < 0.01, c
    assert rows[0]["ate_sim3_rmse_m"] == pytest.approx(res["ate_sim3"]["rmse_m"])
    text = format_report(res)
    assert "components/01/trajectory.txt" in text and "% of path" in text
    saved = json.loads((out / "evaluation.json").read_text())
    assert [c["id"] for c in saved["components"]] == [0, 1]


@pytest.mark.e2e
def test_cli_min_frames_off_writes_no_component_and_overwrite_leaves_no_mix(two_scenes, tmp_path):
    out = tmp_path / "out"
    args = ["run", str(two_scenes), "--out", str(out), "--set", "fusion.enabled=false", "--quiet"]
    assert main(args) == 0
    assert (out / "components/01/trajectory.txt").is_file() and not (out / "components/01/mesh.ply").exists()
    assert main([*args, "--overwrite", "--set", "components.min_frames=0"]) == 0
    s = json.loads((out / "summary.json").read_text())
    assert s["config"]["components"]["min_frames"] == 0
    assert [c["not_written"] for c in s["components"]] == [None, "off"] and s["components"][1]["files"] == []
    assert not (out / "components").exists()  # the earlier run's components went with it


@pytest.mark.e2e
def test_min_frames_filters_small_components(two_scenes, tmp_path):
    cfg = slam_preset("colon", components={"min_frames": FRAMES_B + 1}, fusion={"enabled": False})
    s = run_slam(two_scenes, tmp_path / "out", cfg, progress=False)
    assert [c["not_written"] for c in s["components"]] == [None, "below_min_frames"]
    assert s["components"][1]["frames"] == FRAMES_B and not (tmp_path / "out" / "components").exists()


def _component(frames: int) -> MapComponent:
    rows = np.arange(frames)
    return MapComponent(rows, np.repeat(np.eye(4)[None], frames, axis=0), frozenset({0}), 1)


def test_plan_writes_the_largest_components_above_min_frames(tmp_path):
    comps = [_component(n) for n in (50, 40, 35, 31, 30, 29)]
    plan = plan_components(comps, ComponentConfig(min_frames=30, max_written=2), RunOutputs(tmp_path))
    assert [e.not_written for e in plan] == [None, None, None, "over_max_written", "over_max_written",
                                            "below_min_frames"]
    assert plan[0].outputs.root == tmp_path and plan[2].outputs.root == tmp_path / "components" / "02"
    assert all(e.outputs is None for e in plan[3:])
    assert [e.not_written for e in plan_components(comps, ComponentConfig(min_frames=0), RunOutputs(tmp_path))][1:] \
        == ["off"] * 5


def _place_run(places: list[int], **cfg) -> tuple[FragmentSlam, PlaceWorld]:
    """FragmentSlam on a fake place world: with graded matches and 40 required
    correspondences, a frame at the previous frame's place extends its fragment and a
    frame one place on opens a new fragment (a keyframe)."""
    world = PlaceWorld(260, reach=2, graded=True)
    c = slam_preset("colon", fragments={"min_correspondences": 40}, fusion={"enabled": False}, **cfg)
    slam = FragmentSlam(c.for_frame_size(128, 128), np.eye(3))
    slam.match = world.match
    for i, place in enumerate(places):
        slam.add(FrameInput(world.frame(i, place), np.full((8, 8), 0.03)))
    return slam, world


#: 30 frames pausing at three places (3 keyframes), then a jump to an unrelated part of the world
#: walked one place per frame (10 frames, 10 keyframes) and a third, short part (5 frames)
PAUSES = [0] * 10 + [1] * 10 + [2] * 10
WALK = list(range(100, 110))
SHORT = list(range(200, 205))


def test_main_map_is_the_component_with_the_most_frames_not_keyframes():
    slam, world = _place_run(PAUSES + WALK + SHORT)
    assert not slam.map.in_main(0)  # while running, the main component is the one with the most keyframes
    slam.finish()
    comps = slam.map.components()
    assert [c.frames for c in comps] == [30, 10, 5] and [c.keyframes for c in comps] == [3, 10, 5]
    assert slam.map.in_main(0) and comps[0].rows.tolist() == list(range(30))
    _, _, poses, reg = slam.map.trajectory()
    assert reg.tolist() == [True] * 30 + [False] * 15
    # the walk in its own world frame (its first keyframe), optimised on its own: exact
    T0 = world.poses[WALK[0]]
    for row, pose in zip(comps[1].rows.tolist(), comps[1].poses):
        assert np.allclose(pose, g.relative_pose(T0, world.poses[(PAUSES + WALK)[row]]), atol=1e-6)
    assert slam.map.keyframe_graph().nodes[3].lone and not slam.map.keyframe_graph().nodes[0].lone


def test_components_are_optimised_only_when_written():
    """The final optimisation covers the main map and the components to be written, not the
    short ones (the walk needs one: it has more than one keyframe; the short part too)."""
    runs = {}
    for min_frames in (10, 0):
        slam, _ = _place_run(PAUSES + WALK + SHORT, components={"min_frames": min_frames})
        before = slam.map.schedule.counts.optimizations
        slam.finish()
        runs[min_frames] = slam.map.schedule.counts.optimizations - before
    assert runs == {10: 2, 0: 1}


def test_a_break_that_rejoins_leaves_one_component():
    """The stream of tests/test_slam_rejoin.py: its frames after the break join the map, so
    there is nothing to write beside it."""
    from tests.test_slam_rejoin import WALK as REJOIN_WALK
    from tests.test_slam_rejoin import _run

    slam = _run(PlaceWorld(30, reach=2), REJOIN_WALK)
    comps = slam.map.components()
    assert len(comps) == 1 and comps[0].frames == len(REJOIN_WALK)
