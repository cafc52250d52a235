"""Re-joining across tracking breaks: frames after a break are matched to the
frames tracked just before it, and the two components merge; thresholds from the frame size."""

from __future__ import annotations

import numpy as np
import pytest

from c3f_core.errors import InputError
from c3f_slam import geometry as g
from c3f_slam.config import FragmentConfig
from c3f_slam.config import preset as slam_preset
from c3f_slam.pipeline import SlamConfig
from c3f_slam.pipeline.frame_step import FrameDecision, FrameInput
from c3f_slam.pipeline.rejoin import _tail_index
from c3f_slam.pipeline.slam import FragmentSlam
from tests.fake_places import PlaceWorld

#: places visited: a smooth walk 0..20, a jump to 24 (a tracking break: out of the matcher's
#: reach of 2 places), back to 22 and a pause there. The keyframe of the first fragment sits at
#: place 0, so only the frames just before the break (place 20) can link 22 to the map.
WALK = list(range(21)) + [24, 23] + [22] * 8


def _run(world: PlaceWorld, places: list[int], **rejoin) -> FragmentSlam:
    return _run_with_decisions(world, places, **rejoin)[0]


def _run_with_decisions(world: PlaceWorld, places: list[int], **rejoin) -> tuple[FragmentSlam, list[FrameDecision]]:
    cfg = slam_preset("colon", fragments={"min_correspondences": 40}, fusion={"enabled": False},
                                   rejoin=rejoin)
    slam = FragmentSlam(cfg.for_frame_size(128, 128), np.eye(3))
    world.use(slam)
    decisions = [slam.add(FrameInput(world.frame(i, place), np.full((8, 8), 0.03))) for i, place in enumerate(places)]
    slam.finish()
    return slam, decisions


def test_frames_after_a_break_rejoin_the_map_at_the_right_place():
    world = PlaceWorld(30, reach=2)
    slam, d = _run_with_decisions(world, WALK)
    _, _, poses, reg = slam.map.trajectory()
    assert reg.all(), f"unregistered frames: {np.flatnonzero(~reg).tolist()}"
    stats = slam.stats()
    assert stats["tracking_breaks"] == 1 and stats["breaks_rejoined"] == 1 and stats["rejoin_edges"] == 1
    # frame 21 (place 24) breaks tracking: a lone keyframe opened for too few correspondences;
    # frame 23 (place 22, within reach of place 20 before the break) re-joins the map
    assert (d[21].kind, d[21].reason) == ("lone", "correspondences")
    assert [k for k, x in enumerate(d) if x.rejoined] == [23]
    # every pose where the world says, relative to the first frame (world = first keyframe)
    T0 = world.poses[WALK[0]]
    for i, place in enumerate(WALK):
        expected = g.relative_pose(T0, world.poses[place])
        assert np.allclose(poses[i], expected, atol=1e-6), (i, place)


def test_without_rejoin_the_frames_after_the_break_are_lost():
    """The same stream with re-joining off: the frames after the break form a lone component
    (so the test above can fail)."""
    slam = _run(PlaceWorld(30, reach=2), WALK, enabled=False)
    _, _, _, reg = slam.map.trajectory()
    assert reg[:21].all() and not reg[21:].any()
    assert slam.stats()["breaks_rejoined"] == 0


def test_a_break_that_never_comes_back_is_dropped_after_its_window():
    """Frames that never return near the break: no rejoin edge, the tail expires (no matching
    cost after ``rejoin.window`` frames)."""
    places = list(range(11)) + list(range(20, 30))  # jump from 10 to 20, never back
    slam = _run(PlaceWorld(31, reach=2), places, window=4)
    stats = slam.stats()
    assert stats["tracking_breaks"] == 1 and stats["breaks_rejoined"] == 0
    assert stats["rejoin_attempts"] == 4 and not slam.rejoin.pending


#: a break the normal matcher cannot bridge: a jump from 20 to 24, then the camera stays at 23,
#: three places (15 mm, 3.4 deg) from the last tracked frame -- within the relaxed filter's reach only
STAY = list(range(21)) + [24] + [23] * 12


def test_a_relaxed_match_just_after_the_break_rejoins():
    world = PlaceWorld(30, reach=2, relaxed_reach=3)
    slam = _run(world, STAY, relaxed_max_step=0.01)
    _, _, poses, reg = slam.map.trajectory()
    assert reg[:21].all() and reg[22:].all()
    stats = slam.stats()
    assert stats["breaks_rejoined"] == 1 and stats["breaks_rejoined_relaxed"] == 1
    T0 = world.poses[0]
    for i in range(22, len(STAY)):
        assert np.allclose(poses[i], g.relative_pose(T0, world.poses[STAY[i]]), atol=1e-6), i


@pytest.mark.parametrize("over", [
    {"relaxed_min_matches": 0},  # relaxed matching off
    {"relaxed_max_step": 0.001},  # 15 mm is more than the camera moves in 10 frames at 1 mm/frame
    {"relaxed_max_turn_deg": 0.1},  # 3.4 deg likewise
])
def test_relaxed_rejoin_needs_a_plausible_motion(over):
    """The same stream: without the relaxed matcher, or with a motion bound the link breaks,
    the frames after the break stay a lone component (so the test above can fail)."""
    slam = _run(PlaceWorld(30, reach=2, relaxed_reach=3), STAY, **{"relaxed_max_step": 0.01, **over})
    _, _, _, reg = slam.map.trajectory()
    assert reg[:21].all() and not reg[22:].any()
    assert slam.stats()["breaks_rejoined_relaxed"] == 0


def test_relaxed_matching_only_in_the_first_frames_after_a_break():
    """Past ``relaxed_frames`` only the normal filter is tried: a camera that reaches the relaxed
    reach later is not joined by it."""
    places = list(range(21)) + [24] * 12 + [23] * 6
    slam = _run(PlaceWorld(30, reach=2, relaxed_reach=3), places, relaxed_max_step=0.01, relaxed_frames=10)
    assert slam.stats()["breaks_rejoined"] == 0


def test_tail_attempts_favour_the_last_tracked_frame():
    order = [_tail_index(t, 4) for t in range(8)]
    assert order == [0, 1, 0, 2, 0, 3, 0, 1]
    assert [_tail_index(t, 1) for t in range(3)] == [0, 0, 0]


@pytest.mark.parametrize(("size", "expected"), [((128, 128), 15), ((256, 256), 25), ((512, 512), 100),
                                                ((1024, 768), 300)])
def test_min_correspondences_scale_with_the_frame_size(size, expected):
    """The paper's 100 at 512 x 512, scaled with the pixel count, at least 1.5 x min_matches (10)."""
    cfg = SlamConfig().for_frame_size(*size)
    assert cfg.fragments.min_correspondences == expected
    given = slam_preset("colon", fragments={"min_correspondences": 42}).for_frame_size(*size)
    assert given.fragments.min_correspondences == 42  # an explicit value is kept
    assert FragmentConfig().correspondences_for(*size, min_matches=10) == expected


def test_unresolved_threshold_is_refused_by_the_backend():
    with pytest.raises(ValueError, match="for_frame_size"):
        FragmentSlam(SlamConfig(), np.eye(3))


def test_rejoin_options_are_checked():
    with pytest.raises(InputError, match="rejoin.window"):
        slam_preset("colon", rejoin={"window": 0})
    with pytest.raises(InputError, match="rejoin.relaxed_min_matches"):
        slam_preset("colon", rejoin={"relaxed_min_matches": 3})
    with pytest.raises(InputError, match="rejoin.relaxed_max_step"):
        slam_preset("colon", rejoin={"relaxed_max_step": 0})
