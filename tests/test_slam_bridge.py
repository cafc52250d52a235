"""The motion bridge: a frame that no match reached is placed by the velocity of the links
before it, if the predicted pose passes its residual checks; a cut to another view is refused,
and the map stays one across a single failed link."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from c3f_core.errors import InputError
from c3f_slam import geometry as g
from c3f_slam.config import FallbackConfig
from c3f_slam.config import preset as slam_preset
from c3f_slam.pipeline.fallback import MAX_BRIDGE_STEPS, MotionBridge, RgbdFrame, scaled_motion
from c3f_slam.pipeline.frame_step import FrameInput
from c3f_slam.pipeline.frontend import PairMatch
from c3f_slam.pipeline.slam import FragmentSlam
from tests.fake_places import PlaceWorld

K = np.array([[80.0, 0, 48], [0, 80.0, 48], [0, 0, 1]])
STEP = g.make_pose(g.axis_angle_to_matrix([0.0, 0.01, 0.0]), [0.0005, 0.0, 0.0002])  # T_prev,cur per frame
DT = 1 / 30


def _wall(seed: int) -> RgbdFrame:
    """A 96x96 textured wall 5 cm in front of the camera (texture from ``seed``)."""
    rng = np.random.default_rng(seed)
    tex = cv2.GaussianBlur(rng.uniform(0, 255, (96, 96)).astype(np.float32), (0, 0), 2.0)
    tex = cv2.normalize(tex, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)
    return RgbdFrame.from_rgb(np.repeat(tex[..., None], 3, axis=2), np.full((96, 96), 0.05, np.float32))


def _bridge(links: int = 4, **cfg) -> MotionBridge:
    """A bridge that has seen ``links`` links of STEP, DT apart; the last frame at t = links * DT."""
    b = MotionBridge(FallbackConfig(**cfg), K)
    b.remember(_wall(0), 0.0, None, bridged=False)
    for k in range(1, links + 1):
        b.remember(_wall(0), k * DT, PairMatch(STEP, np.zeros((0, 3)), 40), bridged=False)
    return b


def test_scaled_motion_continues_a_rotation_and_a_translation():
    turn = g.make_pose(g.axis_angle_to_matrix([0.0, 0.2, 0.0]), [0.0, 0.0, 0.0])
    half = scaled_motion(turn, 0.5)
    assert np.allclose(half @ half, turn, atol=1e-12)
    shift = g.make_pose(np.eye(3), [0.001, -0.002, 0.003])
    assert np.allclose(scaled_motion(shift, 3.0)[:3, 3], [0.003, -0.006, 0.009])
    screw = STEP @ STEP @ STEP  # a constant twist: a third of three steps is one step
    assert np.allclose(scaled_motion(screw, 1 / 3), STEP, atol=1e-12)
    assert np.allclose(scaled_motion(turn, 1.0), turn) and np.allclose(scaled_motion(turn, 0.0), np.eye(4))


def test_the_prediction_is_the_mean_velocity_scaled_to_the_time_since_the_last_frame():
    b = _bridge()
    T, steps = b.predict(5 * DT)
    assert steps == pytest.approx(1.0) and np.allclose(T, STEP, atol=1e-9)
    T2, steps2 = b.predict(6 * DT)  # one frame skipped: two steps of motion
    assert steps2 == pytest.approx(2.0) and np.allclose(T2, scaled_motion(STEP, 2.0), atol=1e-9)
    assert b.predict(4 * DT + (MAX_BRIDGE_STEPS + 0.5) * DT) is None  # too long a gap
    assert b.predict(4 * DT) is None  # no time has passed


def test_the_velocity_is_the_mean_of_the_window():
    """One link off by 4 degrees among four: the prediction is off by a quarter of it."""
    b = MotionBridge(FallbackConfig(bridge_window=4), K)
    b.remember(_wall(0), 0.0, None, bridged=False)
    off = STEP @ g.make_pose(g.axis_angle_to_matrix([0.0, np.radians(4.0), 0.0]), [0, 0, 0])
    for k, T in enumerate([STEP, STEP, STEP, off], start=1):
        b.remember(_wall(0), k * DT, PairMatch(T, np.zeros((0, 3)), 40), bridged=False)
    T, _ = b.predict(5 * DT)
    _, turn = g.motion_magnitudes((g.invert_pose(STEP) @ T)[None])
    assert turn[0] == pytest.approx(1.0, abs=0.05)


def test_no_prediction_without_links_or_after_bridging_the_most_frames_in_a_row():
    b = _bridge()
    b.remember(_wall(0), 5 * DT, None, bridged=False)  # a frame without a link: the motion is unknown
    assert b.predict(6 * DT) is None
    b = _bridge(bridge_max_frames=2)
    b.remember(_wall(0), 5 * DT, PairMatch(STEP, np.zeros((0, 3)), 1), bridged=True)
    assert b.predict(6 * DT) is not None
    b.remember(_wall(0), 6 * DT, PairMatch(STEP, np.zeros((0, 3)), 1), bridged=True)
    assert b.predict(7 * DT) is None


def test_a_continuation_is_bridged_and_a_cut_to_another_view_is_refused():
    b = _bridge(points=100, trust=0.05)
    m = b.link(_wall(0), 5 * DT)  # the same wall (the bridge's step barely moves its texture)
    assert m is not None and np.allclose(m.T_ij, STEP, atol=1e-9)
    assert len(m.points_j) == 100 and m.n == 5
    cut = _bridge()
    assert cut.link(_wall(7), 5 * DT) is None  # another texture: the intensity residual fails
    assert cut.outcomes == {"photometric_residual": 1}
    assert b.stats() == {"bridge_attempts": 1, "bridge_outcomes": {"accepted": 1}}


def test_a_fast_prediction_is_refused_as_implausible_unless_frames_were_skipped():
    fast = g.make_pose(np.eye(3), [0.004, 0.0, 0.0])  # 4 mm per frame; max_step 5 mm
    b = MotionBridge(FallbackConfig(max_step=0.005, bridge_min_inlier_share=0.01,
                                    bridge_max_photometric_rmse=1.0), K)
    b.remember(_wall(0), 0.0, None, bridged=False)
    b.remember(_wall(0), DT, PairMatch(fast, np.zeros((0, 3)), 40), bridged=False)
    assert b.link(_wall(0), 3 * DT) is not None  # 8 mm over two steps: plausible
    b.remember(_wall(0), 0.0, None, bridged=False)
    b.remember(_wall(0), DT, PairMatch(g.make_pose(np.eye(3), [0.006, 0, 0]), np.zeros((0, 3)), 40), bridged=False)
    assert b.link(_wall(0), 2 * DT) is None and b.outcomes["implausible_motion"] == 1


def test_bridge_options_are_checked():
    with pytest.raises(InputError, match="fallback.bridge_max_frames"):
        slam_preset("colon", fallback={"bridge_max_frames": 0})
    with pytest.raises(InputError, match="fallback.bridge_min_inlier_share"):
        slam_preset("colon", fallback={"bridge_min_inlier_share": 0.0})
    assert slam_preset("colon").fallback.bridge


class FoldWorld(PlaceWorld):
    """Places along a path at constant speed; frames from ``fold`` on match no frame before it
    (a fold swept through the view), frames on either side match as usual."""

    def __init__(self, n: int, fold: int) -> None:
        super().__init__(n, reach=2)
        self.fold = fold

    def match(self, a, b, reach=None):
        if (self.place[a.index] < self.fold) != (self.place[b.index] < self.fold):
            return None, 0
        return super().match(a, b, reach)


def _fold_run(bridge: bool) -> FragmentSlam:
    world = FoldWorld(30, fold=15)
    cfg = slam_preset("colon", fragments={"min_correspondences": 40}, fusion={"enabled": False},
                      fallback={"bridge": bridge})
    slam = world.use(FragmentSlam(cfg.for_frame_size(96, 96), K))
    for i in range(30):  # a textured wall: the bridge's checks pass, as on a wall seen from a steady path
        slam.add(FrameInput(world.frame(i, i), np.full((96, 96), 0.05), np.repeat(
            cv2.GaussianBlur(np.random.default_rng(0).uniform(0, 255, (96, 96)), (0, 0), 2.0)[..., None], 3,
            axis=2).astype(np.uint8)))
    slam.finish()
    return slam, world


def test_the_map_stays_one_across_a_single_failed_link():
    lost, _ = _fold_run(bridge=False)
    assert not lost.map.trajectory()[3][15:].any()
    slam, world = _fold_run(bridge=True)
    _, _, poses, registered = slam.map.trajectory()
    assert registered.all()
    stats = slam.stats()
    assert stats["bridge_outcomes"] == {"accepted": 1} and stats["fallback_edges"] == 1
    assert stats["tracking_breaks"] == 0
    # after the fold the path is off by the bridge's error only: the places turn 0.02 rad per
    # step, so the mean velocity of four links misses the next step by well under a millimetre
    truth = [g.relative_pose(world.poses[0], world.poses[i]) for i in range(30)]
    err = max(np.linalg.norm(poses[i][:3, 3] - truth[i][:3, 3]) for i in range(30))
    assert err < 1e-3
    assert np.allclose(poses[:15], truth[:15], atol=1e-6)
