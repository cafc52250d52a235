"""A fake world for back-end tests of ``FragmentSlam`` without images: frames sit at known
places and a fake matcher stands in for descriptor matching and Kabsch.

Places are 5 mm apart along x (the camera turning 0.02 rad about y per place, looking along
+z); two frames match exactly when their places are within ``reach`` of each other; each
place has its own SIFT-like descriptors. With ``graded`` the match strength (inlier count)
falls by one per place of distance, otherwise every match has 40 inliers.
"""

from __future__ import annotations

import numpy as np

from c3f_slam import geometry as g
from c3f_slam.config import preset as slam_preset
from c3f_slam.pipeline.frontend import FrameFeatures, PairMatch
from c3f_slam.pipeline.slam import FragmentSlam

N_POINTS = 40


def sift_like(rng: np.random.Generator, n: int = 60) -> np.ndarray:
    """SIFT-like uint8 descriptors: sparse non-negative histograms."""
    d = rng.gamma(0.6, 30.0, (n, 128)) * (rng.random((n, 128)) < 0.5)
    return np.clip(d, 0, 255).astype(np.uint8)


def place_poses(n: int) -> list[np.ndarray]:
    """Camera-to-world poses of ``n`` places, 5 mm apart along x."""
    return [g.make_pose(g.axis_angle_to_matrix([0.0, 0.02 * k, 0.0]), [0.005 * k, 0.0, 0.0]) for k in range(n)]


class PlaceWorld:
    """Frames at known places with an exact fake matcher (see the module docstring)."""

    def __init__(self, n_places: int, reach: int = 2, seed: int = 0, graded: bool = False,
                 relaxed_reach: int | None = None) -> None:
        """``relaxed_reach``: how far apart two places still match with the re-joining's relaxed
        filter (``rejoin.relaxed_min_matches``; None: as far as the normal one)."""
        rng = np.random.default_rng(seed)
        self.poses = place_poses(n_places)
        self.desc = [sift_like(rng, N_POINTS) for _ in range(n_places)]
        self.pts = rng.uniform(-0.01, 0.01, (N_POINTS, 3)).astype(np.float32) + np.float32([0, 0, 0.03])
        self.reach = reach
        self.relaxed_reach = reach if relaxed_reach is None else relaxed_reach
        self.graded = graded
        self.place: dict[int, int] = {}

    def frame(self, index: int, place: int) -> FrameFeatures:
        self.place[index] = place
        xy = np.zeros((N_POINTS, 2), np.float32)
        return FrameFeatures(index, index / 30.0, xy, self.desc[place], self.pts.copy())

    def match(self, a: FrameFeatures, b: FrameFeatures, reach: int | None = None) -> tuple[PairMatch | None, int]:
        pa, pb = self.place[a.index], self.place[b.index]
        if abs(pa - pb) > (self.reach if reach is None else reach):
            return None, 0
        n = N_POINTS - abs(pa - pb) if self.graded else N_POINTS
        return PairMatch(g.relative_pose(self.poses[pa], self.poses[pb]), self.pts[:n].astype(float), n), n

    def guided(self, a: FrameFeatures, b: FrameFeatures, T_prior: np.ndarray, radius_px: float
               ) -> tuple[PairMatch | None, int]:
        """Guided matching in this world: exact, the prior changes nothing (:meth:`match`)."""
        return self.match(a, b)

    def relaxed(self, a: FrameFeatures, b: FrameFeatures) -> tuple[PairMatch | None, int]:
        """The re-joining's relaxed matching in this world: exact, within ``relaxed_reach``."""
        return self.match(a, b, self.relaxed_reach)

    def use(self, slam: FragmentSlam) -> FragmentSlam:
        """``slam`` with this world's matchers (plain, guided and, where on, relaxed)."""
        slam.match, slam.recovery.guided = self.match, self.guided
        if slam.rejoin.relaxed is not None:
            slam.rejoin.relaxed = self.relaxed
        return slam


def keyframe_per_frame_slam(world: PlaceWorld, **over) -> FragmentSlam:
    """A FragmentSlam on ``world``'s matcher in which every frame opens a fragment (no frame
    reaches 10^6 correspondences): one keyframe per frame. ``over``: SlamConfig parts (dicts)."""
    cfg = slam_preset("colon", fragments={"min_correspondences": 10**6}, fusion={"enabled": False},
                                   **over)
    return world.use(FragmentSlam(cfg.for_frame_size(128, 128), np.eye(3)))
