"""The dense fallback where sparse matching fails: its edge bridges a tracking
break, carries trust-weighted information, and is pruned when keyframe matches contradict it;
the dense aligner's own verification on rendered frames."""

from __future__ import annotations

import numpy as np
import pytest

from c3f_core.errors import InputError
from c3f_slam import geometry as g
from c3f_slam.config import FallbackConfig
from c3f_slam.config import preset as slam_preset
from c3f_slam.pipeline import SlamConfig
from c3f_slam.pipeline.fallback import DenseFallback, RgbdFrame, verify_alignment
from c3f_slam.pipeline.frame_step import FrameInput
from c3f_slam.pipeline.frontend import PairMatch
from c3f_slam.pipeline.slam import FragmentSlam
from c3f_slam.posegraph import EdgeKind
from tests.fake_places import PlaceWorld

RGB, DEPTH = np.zeros((8, 8, 3), np.uint8), np.full((8, 8), 0.03)


class PlantedFallback(DenseFallback):
    """A fallback that answers its first alignment with ``T_ij`` (and nothing after it)."""

    def __init__(self, cfg: FallbackConfig, T_ij: np.ndarray) -> None:
        super().__init__(cfg, np.eye(3))
        self.T_ij = T_ij
        self.calls = 0

    def align(self, cur: RgbdFrame, init: np.ndarray | None = None) -> PairMatch | None:
        self.calls += 1
        if self.calls > 1:
            return None
        self.outcomes["accepted"] += 1
        pts = np.random.default_rng(0).uniform(-0.01, 0.01, (self.cfg.points, 3)) + [0, 0, 0.03]
        return PairMatch(self.T_ij, pts, self.strength(len(pts)))


def _run(world: PlaceWorld, places: list[int], T_break: np.ndarray | None, keyframe_per_frame: bool,
         sparse_components: bool = True, **fallback) -> FragmentSlam:
    """``places`` with a tracking break wherever consecutive places are out of the matcher's
    reach; the fallback (if ``T_break``) answers the first break with ``T_break``. The motion
    bridge is off (tests/test_slam_bridge.py has it): these frames are blank, so its checks
    would pass anything."""
    frag = {"min_correspondences": 10**6 if keyframe_per_frame else 40}
    cfg = slam_preset("colon", fragments=frag, fusion={"enabled": False},
                                   fallback={"dense": T_break is not None, "bridge": False, **fallback})
    slam = FragmentSlam(cfg.for_frame_size(128, 128), np.eye(3))
    world.use(slam)
    if T_break is not None:
        slam.recovery.dense = PlantedFallback(cfg.fallback, T_break)
        if not sparse_components:
            slam.map.sparse = None
    for i, place in enumerate(places):
        slam.add(FrameInput(world.frame(i, place), DEPTH, RGB))
    slam.finish()
    return slam


def _poses_right(world: PlaceWorld, places: list[int], poses: np.ndarray, atol: float) -> bool:
    T0 = world.poses[places[0]]
    return all(np.allclose(poses[i], g.relative_pose(T0, world.poses[p]), atol=atol) for i, p in enumerate(places))


#: a walk 0..20, a jump to 24 (out of the matcher's reach of 2 places), then on to 34, never back
AWAY = list(range(21)) + list(range(24, 35))
#: the same jump, then back over 23, 22, 21 (keyframe matches to the frames before the break)
BACK = list(range(21)) + [24, 23, 22, 21, 21, 21]


def test_a_verified_fallback_bridges_a_break_that_never_comes_back():
    world = PlaceWorld(40, reach=2)
    lost = _run(world, AWAY, None, keyframe_per_frame=False)
    assert not lost.map.trajectory()[3][21:].any()  # without the fallback the frames after the jump are lost
    true_step = g.relative_pose(world.poses[20], world.poses[24])
    slam = _run(world, AWAY, true_step, keyframe_per_frame=False)
    _, _, poses, reg = slam.map.trajectory()
    assert reg.all()
    assert _poses_right(world, AWAY, poses, 1e-6)
    stats = slam.stats()
    assert stats["fallback_edges"] == 1 and stats["fallback_edges_pruned"] == 0
    assert stats["fallback_outcomes"] == {"accepted": 1} and stats["tracking_breaks"] == 0


@pytest.mark.parametrize("deg, metres", [(10.0, 0.02), (3.0, 0.005), (30.0, 0.05)])
def test_a_planted_wrong_fallback_edge_is_pruned(deg, metres):
    """A fallback edge off by ``deg`` and ``metres``; the frames after the jump come back and
    match the keyframes before it: those matches re-place the side after the fallback edge,
    the line process prunes the fallback edge, not the matches, and every pose ends where the
    world says."""
    world = PlaceWorld(40, reach=2)
    wrong = g.relative_pose(world.poses[20], world.poses[24]) @ g.make_pose(
        g.axis_angle_to_matrix([0.0, np.radians(deg), 0.0]), [metres, 0.0, 0.0])
    slam = _run(world, BACK, wrong, keyframe_per_frame=True)
    stats = slam.stats()
    assert stats["fallback_edges"] == 1 and stats["fallback_edges_pruned"] == 1, stats
    kinds = {e.kind for e in slam.map.keyframe_graph().edges if e.pruned}
    assert kinds == {EdgeKind.FALLBACK.value}
    _, _, poses, reg = slam.map.trajectory()
    assert reg.all() and _poses_right(world, BACK, poses, 1e-4)


def test_a_right_fallback_edge_is_kept_when_the_matches_agree():
    world = PlaceWorld(40, reach=2)
    slam = _run(world, BACK, g.relative_pose(world.poses[20], world.poses[24]), keyframe_per_frame=True)
    assert slam.stats()["fallback_edges_pruned"] == 0 and slam.stats()["pruned_edges"] == 0
    assert _poses_right(world, BACK, slam.map.trajectory()[2], 1e-6)


def test_without_sparse_components_the_matches_are_pruned_instead():
    """The control: placing new keyframes by the graph's components (the fallback edge counts
    as a link), the matches that contradict the wrong edge start far off and are pruned; the
    wrong edge stays and the poses after the jump are wrong (so the test above can fail)."""
    world = PlaceWorld(40, reach=2)
    wrong = g.relative_pose(world.poses[20], world.poses[24]) @ g.make_pose(
        g.axis_angle_to_matrix([0.0, np.radians(10.0), 0.0]), [0.02, 0.0, 0.0])
    slam = _run(world, BACK, wrong, keyframe_per_frame=True, sparse_components=False)
    stats = slam.stats()
    assert stats["fallback_edges_pruned"] == 0 and stats["pruned_edges"] > 0
    assert not _poses_right(world, BACK, slam.map.trajectory()[2], 1e-3)


# ---------------------------------------------------------------------- the dense aligner


def _textured_wall(seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A 96x96 frame of a textured wall 5 cm in front of the camera, tilted (rgb, depth m, K)."""
    import cv2

    rng = np.random.default_rng(seed)
    tex = cv2.GaussianBlur(rng.uniform(0, 255, (96, 96)).astype(np.float32), (0, 0), 2.0)
    tex = cv2.normalize(tex, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)
    K = np.array([[80.0, 0, 48], [0, 80.0, 48], [0, 0, 1]])
    v, u = np.mgrid[0:96, 0:96]
    depth = (0.05 + 0.0002 * (u - 48)).astype(np.float32)
    return np.repeat(tex[..., None], 3, axis=2), depth, K


def test_verification_accepts_the_true_motion_and_rejects_a_wrong_one():
    """Consecutive frames of the same view (no motion): identity verifies; a 3 mm sideways
    shift moves the wall's texture ~5 px and fails the photometric residual; a 3 cm step fails
    the plausibility bound."""
    rgb, depth, K = _textured_wall()
    frame = RgbdFrame.from_rgb(rgb, depth)
    cfg = FallbackConfig(dense=True)
    ok = verify_alignment(np.eye(4), frame, frame, K, cfg.max_depth_residual)
    assert ok.failure(cfg) is None and ok.inlier_share > 0.99 and ok.photometric_rmse < 1e-6
    shifted = verify_alignment(g.make_pose(np.eye(3), [0.003, 0, 0]), frame, frame, K, cfg.max_depth_residual)
    assert shifted.failure(cfg) == "photometric_residual", shifted
    far = verify_alignment(g.make_pose(np.eye(3), [0.03, 0, 0]), frame, frame, K, cfg.max_depth_residual)
    assert far.failure(cfg) == "implausible_motion"


def test_dense_fallback_aligns_a_pair_and_weights_its_information():
    rgb, depth, K = _textured_wall()
    fb = DenseFallback(FallbackConfig(dense=True, trust=0.05, points=200), K)
    fb.remember(RgbdFrame.from_rgb(rgb, depth))
    m = fb.align(RgbdFrame.from_rgb(rgb, depth))
    assert m is not None and fb.outcomes == {"accepted": 1}
    step, turn = g.motion_magnitudes(m.T_ij[None])
    assert step[0] < 1e-4 and turn[0] < 0.1
    assert len(m.points_j) == 200 and m.n == 10
    assert fb.information(m)[5, 5] == pytest.approx(0.05 * 200)
    fb.remember(None)  # a gap: nothing to align to
    assert fb.align(RgbdFrame.from_rgb(rgb, depth)) is None


def test_fallback_options_are_checked():
    with pytest.raises(InputError, match="fallback.trust"):
        slam_preset("colon", fallback={"trust": 0.0})
    with pytest.raises(InputError, match="fallback.points"):
        slam_preset("colon", fallback={"points": 2})
    assert not SlamConfig().fallback.dense and SlamConfig().fallback.guided
    assert slam_preset("room").fallback.max_step == 0.1


# ---------------------------------------------------------------------- guided matching


def _repeated_texture_pair() -> tuple:
    """Frames i, j of 20 points 3 cm away where every descriptor occurs twice (repeated
    texture): the plain ratio test rejects every match; frame j moved 1 mm along x."""
    from c3f_slam.pipeline.frontend import FrameFeatures

    rng = np.random.default_rng(3)
    pts_i = np.column_stack([rng.uniform(-0.01, 0.01, (20, 2)), np.full(20, 0.03)])
    T_ij = g.make_pose(np.eye(3), [0.001, 0.0, 0.0])  # p_i = T_ij p_j
    pts_j = pts_i - [0.001, 0.0, 0.0]
    K = np.array([[100.0, 0, 64], [0, 100.0, 64], [0, 0, 1]])
    desc = np.repeat(rng.uniform(0, 1, (10, 128)), 2, axis=0).astype(np.float32)
    xy_j = (pts_j @ K.T)[:, :2] / pts_j[:, 2:]
    fi = FrameFeatures(0, 0.0, np.zeros((20, 2), np.float32), desc, pts_i.astype(np.float32))
    fj = FrameFeatures(1, 0.03, xy_j.astype(np.float32), desc, pts_j.astype(np.float32))
    return fi, fj, T_ij, K


def test_projection_mask_keeps_the_pairs_near_the_prior():
    from c3f_slam.pipeline.frontend import projection_mask

    fi, fj, T_ij, K = _repeated_texture_pair()
    mask = projection_mask(fi, fj, T_ij, K, 1.0)
    assert np.array_equal(mask, np.eye(20, dtype=bool))  # exact prior: each point on its own keypoint
    assert projection_mask(fi, fj, np.eye(4), K, 1.0).sum() < 20  # a 3 px wrong prior misses at 1 px
    pts = fi.points.copy()
    pts[0] = np.nan
    no_depth = type(fi)(fi.index, fi.timestamp, fi.xy, fi.descriptors, pts)
    assert not projection_mask(no_depth, fj, T_ij, K, 50.0)[0].any()  # no depth: matches nothing


def test_guided_matching_finds_what_the_ratio_test_rejects():
    from c3f_slam.pipeline.frontend import guided_matcher, match_frames

    fi, fj, T_ij, K = _repeated_texture_pair()
    cfg = SlamConfig().for_frame_size(128, 128)
    assert match_frames(fi, fj, cfg.match_filter, "l2", cfg.frontend.ratio)[0] is None
    m, n = guided_matcher(cfg, K)(fi, fj, np.eye(4), 6.0)  # prior: no motion (3 px off)
    assert m is not None and n == 20
    assert np.allclose(m.T_ij, T_ij, atol=1e-6)


def test_guided_matching_bridges_a_break_in_the_back_end():
    """A stream whose plain matcher fails once: the guided matcher (here exact) links the
    frame, no break is counted, every frame is in one map; with ``fallback.guided`` off the
    same stream breaks (and re-localises through a keyframe match)."""
    world = PlaceWorld(40, reach=2)
    places = list(range(30))

    def run(guided: bool) -> FragmentSlam:
        cfg = slam_preset("colon", fragments={"min_correspondences": 40}, fusion={"enabled": False},
                                       fallback={"guided": guided}, rejoin={"enabled": False})
        slam = world.use(FragmentSlam(cfg.for_frame_size(128, 128), np.eye(3)))
        slam.match = lambda a, b: (None, 0) if (a.index, b.index) == (14, 15) else world.match(a, b)
        for i, p in enumerate(places):
            slam.add(FrameInput(world.frame(i, p), DEPTH))
        slam.finish()
        return slam

    on, off = run(True), run(False)
    assert on.stats()["guided_links"] == 1 and on.stats()["tracking_breaks"] == 0 and on.map.trajectory()[3].all()
    assert off.stats()["tracking_breaks"] == 1 and off.stats()["guided_links"] == 0
