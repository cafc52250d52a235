"""Settings of tracking: keypoints and matching of each frame, the match filter, the
new-fragment rule, guided / dense fallbacks and re-joining after a break. Lengths in metres,
angles in degrees; each group checks its own fields (InputError naming ``part.field``).
The values of the ``room`` preset: :mod:`c3f_slam.config.presets`."""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

from c3f_slam.config.checks import at_least, check

#: the paper's new-fragment rule (docs/design.md, Fragments and keyframes) is for 512 x 512 frames
PAPER_MIN_CORRESPONDENCES, PAPER_FRAME_PIXELS = 100, 512 * 512
#: the residual bound's share of the depth on predicted depth (``match_filter.residual_relative_tolerance``
#: None with ``--depth-source model``); depth files (sensor or ground truth) take 0
PREDICTED_DEPTH_RESIDUAL_SHARE = 0.03


@dataclass(frozen=True)
class FrontendConfig:
    """Keypoints and descriptor matching of each frame (:class:`c3f_slam.pipeline.frontend.Frontend`)."""

    max_keypoints: int = 1000  #: SIFT keypoints per frame, strongest first
    sift_contrast_threshold: float = 0.005  #: OpenCV's 0.04 finds too few on small, smooth colon frames
    mask_specular: bool = True  #: no keypoints in specular highlights
    #: dilation of the specular mask; None: the paper's 13 px x min(W, H) / 512, at least 3 px
    specular_dilation_px: int | None = None
    ratio: float | None = 0.9  #: Lowe ratio test on top of mutual nearest neighbours; None = off

    def __post_init__(self) -> None:
        at_least(self.max_keypoints, 10, "frontend.max_keypoints")
        check(self.ratio is None or 0 < self.ratio <= 1, f"frontend.ratio must be in (0, 1] or None, got {self.ratio}")


@dataclass(frozen=True)
class MatchFilterConfig:
    """Thresholds of the match filters (lengths in metres, areas in m^2).

    Colon defaults (viewing depths of about 1-6 cm, frames of 128-512 px with 110-125 deg
    field of view, where one pixel spans 0.2-0.7 mm of wall at 3 cm):

    - ``max_residual`` 1 mm: BundleFusion's 2 cm at room scale is about 5 px of a
      640x480 Kinect frame at 2 m; 1 mm is 1.5-5 px at 3 cm here, i.e. the keypoint
      localisation error, not the scene size, sets it.
    - ``pairwise_tolerance`` 2 mm (+5 % of the distance): two endpoints, each off by up to
      ``max_residual``; the relative part absorbs predicted-depth scale error.
    - ``min_area`` 1e-5 m^2 (10 mm^2, e.g. 3x3 mm): BundleFusion's 0.032 m^2 scaled by
      (1/50)^2 (2 m room viewing distance vs about 3-4 cm in the colon).
    - ``residual_relative_tolerance`` None: 3 % of the point's depth on predicted depth (a
      network's depth errs in proportion to the depth, about 9 % on the zoo's held-out
      sequences), 0 on depth files; resolved by :meth:`for_depth_source` when a run starts.
      With it, ``weighted_fit`` (off by default) refits the accepted transform weighting each
      point by 1 / bound^2, so near points (smaller absolute depth error) count more.
    - ``reprojection_refit`` (off by default): the accepted transform is refitted to the
      survivors' symmetric reprojection error
      (:func:`c3f_slam.matching.reprojection.refine_by_reprojection`, Huber
      ``reprojection_huber_px``), which trusts the keypoints' pixels more than the depth. On
      the zoo's depth it halves the ATE of most held-out sequences but moves the unseen-wall
      estimate (docs/design.md).
    - ``max_condition`` 100 and ``min_matches`` 10: BundleFusion / the paper (scale-free).
    """

    min_matches: int = 10  #: fewer surviving correspondences: the set is rejected
    max_residual: float = 1.0e-3  #: metres: largest residual of a kept correspondence after the rigid fit ...
    #: ... plus this share of the point's depth (its z in frame i); 0: the fixed bound alone.
    #: None: from the depth source (:meth:`for_depth_source`: 0.03 on predicted depth, 0 on files)
    residual_relative_tolerance: float | None = None
    #: with a depth-relative bound, refit the survivors' transform weighting each by 1 / bound^2
    #: (the inverse variance of a depth-proportional error); no effect with the fixed bound alone.
    #: Off: on the zoo's depth it lowers ATE but moves the unseen-wall estimate (docs/design.md)
    weighted_fit: bool = False
    #: refit the accepted transform to the survivors' symmetric reprojection error (pixels
    #: trusted, depth only for the translation's length). Off: on the zoo's depth it lowers the
    #: ATE of most sequences but moves the unseen-wall estimate (docs/design.md)
    reprojection_refit: bool = False
    reprojection_huber_px: float = 1.0  #: pixels: Huber threshold of the reprojection refit
    pairwise_tolerance: float = 2.0e-3  #: metres: pairwise distances may differ this much between frames ...
    pairwise_relative_tolerance: float = 0.05  #: ... plus this share of the distance
    max_condition: float = 100.0  #: largest condition number of the fit (near-collinear sets fail)
    min_area: float = 1.0e-5  #: m^2: the set is rejected when both frames' spanned areas are smaller
    use_pairwise: bool = True  #: apply the pairwise-distance consistency test
    use_area: bool = True  #: apply the surface area test
    max_matches: int | None = None  #: keep at most this many candidates (strongest first); None = all

    def __post_init__(self) -> None:
        check(self.min_matches >= 3,
              f"match_filter.min_matches must be >= 3 (a rigid fit needs 3 points), got {self.min_matches}")
        for name in ("max_residual", "pairwise_tolerance", "max_condition", "reprojection_huber_px"):
            check(getattr(self, name) > 0, f"match_filter.{name} must be > 0, got {getattr(self, name)}")
        for name in ("pairwise_relative_tolerance", "min_area"):
            check(getattr(self, name) >= 0, f"match_filter.{name} must be >= 0, got {getattr(self, name)}")
        at_least(self.residual_relative_tolerance, 0, "match_filter.residual_relative_tolerance",
                 "from the depth source")
        at_least(self.max_matches, 3, "match_filter.max_matches", "all")

    @property
    def residual_share(self) -> float:
        """The residual bound's share of the depth in use: ``residual_relative_tolerance``, 0
        while unresolved (None outside a run: depth taken as exact, as from files)."""
        return self.residual_relative_tolerance or 0.0

    def for_depth_source(self, depth_source: str) -> MatchFilterConfig:
        """This filter with ``residual_relative_tolerance`` resolved for ``depth_source``
        (``model``: :data:`PREDICTED_DEPTH_RESIDUAL_SHARE`; ``files``: 0); a given value stays."""
        if self.residual_relative_tolerance is not None:
            return self
        share = PREDICTED_DEPTH_RESIDUAL_SHARE if depth_source == "model" else 0.0
        return replace(self, residual_relative_tolerance=share)

    def scaled(self, factor: float) -> MatchFilterConfig:
        """The same filter for a scene ``factor`` times larger (lengths x f, areas x f^2)."""
        check(factor > 0, f"scale factor must be positive, got {factor}")
        return replace(
            self,
            max_residual=self.max_residual * factor,
            pairwise_tolerance=self.pairwise_tolerance * factor,
            min_area=self.min_area * factor**2,
        )


@dataclass(frozen=True)
class FragmentConfig:
    """When a frame opens a new fragment (docs/design.md, Fragments and keyframes;
    :func:`c3f_slam.pipeline.fragments.new_fragment_reason`)."""

    #: fewer filtered correspondences to the previous frame: new fragment. None: derived from the
    #: frame size (:meth:`correspondences_for`; the paper's 100 at 512 x 512)
    min_correspondences: int | None = None
    min_overlap: float = 0.85  #: lower frustum overlap with the active keyframe: new fragment
    overlap_stride: int = 4  #: pixel grid of the overlap test
    max_frames: int = 60  #: fragment length cap (memory)
    #: match each new frame to every earlier frame of its fragment (its cost grows with the
    #: fragment's length); False: to a bounded set besides the previous frame: the keyframe, the
    #: ``intra_recent`` frames before the previous one and ``intra_spaced`` frames evenly spaced
    #: over the rest (:func:`c3f_slam.pipeline.fragments.intra_fragment_targets`)
    intra_all_pairs: bool = False
    intra_recent: int = 2  #: bounded set: the frames just before the previous one
    intra_spaced: int = 8  #: bounded set: at most this many frames spaced between the keyframe and the recent ones

    def __post_init__(self) -> None:
        at_least(self.min_correspondences, 0, "fragments.min_correspondences", "from the frame size")
        check(0.0 <= self.min_overlap <= 1.0, f"fragments.min_overlap must be in [0, 1], got {self.min_overlap}")
        at_least(self.overlap_stride, 1, "fragments.overlap_stride")
        at_least(self.max_frames, 1, "fragments.max_frames")
        at_least(self.intra_recent, 0, "fragments.intra_recent")
        at_least(self.intra_spaced, 0, "fragments.intra_spaced")

    def correspondences_for(self, width: int, height: int, min_matches: int) -> int:
        """The new-fragment threshold for ``width`` x ``height`` frames: the configured one, else
        the paper's 100 for 512 x 512 scaled with the pixel count (keypoints, and so
        correspondences, grow with the image area), at least 1.5 x the match filter's
        ``min_matches`` (so that a frame just above the filter's floor still opens a new
        fragment): 15 at 128 px, 25 at 256 px, 100 at 512 px."""
        if self.min_correspondences is not None:
            return self.min_correspondences
        scaled = PAPER_MIN_CORRESPONDENCES * width * height / PAPER_FRAME_PIXELS
        return int(max(round(scaled), math.ceil(1.5 * min_matches)))


@dataclass(frozen=True)
class RejoinConfig:
    """How tracking breaks are bridged (:mod:`c3f_slam.pipeline.rejoin`; frames = processed frames)."""

    enabled: bool = True  #: try to join the frames after a break to the frames before it
    #: a frame after skipped frames (black, blurred, repeated, ...: frames.quality) is matched to
    #: the last processed frame as if they were not there; False: every skip breaks the track (a
    #: clip whose picture changes every 3-4 frames then links no two frames: the phantom clip's
    #: 75 usable frames made 74 breaks and a path 3.2 times its 1-second average)
    across_skipped: bool = True
    tail_frames: int = 6  #: frames before a break kept as targets (the last ones, every ``tail_step``-th)
    tail_step: int = 3  #: spacing of the kept tail frames
    window: int = 300  #: frames after a break during which its tail is tried (then it is dropped)
    keypoints: int = 500  #: features a tail frame keeps (strongest first)
    max_pending: int = 4  #: breaks remembered at once (the oldest is dropped)
    #: for the first ``relaxed_frames`` frames after a break, a tail frame the normal filter does not
    #: link is matched again accepting this many correspondences (0 = off), if the motion it gives
    #: is one the camera can make in the frames between (``relaxed_max_step``, ``relaxed_max_turn_deg``)
    relaxed_min_matches: int = 8
    relaxed_frames: int = 10  #: frames after a break during which the relaxed rule applies
    relaxed_max_step: float = 0.003  #: metres per frame a relaxed link may move the camera
    relaxed_max_turn_deg: float = 6.0  #: degrees per frame a relaxed link may turn it

    def __post_init__(self) -> None:
        for name in ("tail_frames", "tail_step", "window", "keypoints", "max_pending"):
            at_least(getattr(self, name), 1, f"rejoin.{name}")
        check(self.relaxed_min_matches == 0 or self.relaxed_min_matches >= 6,
               f"rejoin.relaxed_min_matches must be 0 (off) or >= 6, got {self.relaxed_min_matches}")
        at_least(self.relaxed_frames, 1, "rejoin.relaxed_frames")
        check(self.relaxed_max_step > 0 and 0 < self.relaxed_max_turn_deg <= 180,
               f"rejoin.relaxed_max_step must be > 0 (metres) and rejoin.relaxed_max_turn_deg in (0, 180], "
               f"got {self.relaxed_max_step}, {self.relaxed_max_turn_deg}")


@dataclass(frozen=True)
class FallbackConfig:
    """What is tried where sparse matching found no accepted match to the previous frame
    (:mod:`c3f_slam.pipeline.fallback`).

    ``guided`` (on): match again with the last inter-frame motion as a prior, each keypoint
    only against the keypoints near where the prior puts it (search by projection), through the
    same match filter; an accepted match is an ordinary odometry link. ``dense`` (off): align
    the frames with Open3D's RGB-D odometry, verified on its residuals; its edge is an
    uncertain ``fallback`` edge whose information is ``trust`` x that of its verified points,
    and keyframe matches that reach across it re-place the side after it, so that the pose
    graph prunes a wrong one. Off by default: on the simulator's colon frames Open3D's dense
    odometry is off by about the inter-frame motion itself, and such results pass the
    residual checks (docs/design.md, Tracking breaks; measured in
    docs/lab_notes/2026-12-02-slam-fallback-pairs.md). ``bridge`` (on): where neither found a
    link, the frame is placed by the motion of the last link (constant velocity over the time
    between the frames), if that pose passes the same residual checks; at most
    ``bridge_max_frames`` frames in a row. Its edge is a ``fallback`` edge of the same trust
    (docs/design.md, Tracking breaks).
    """

    guided: bool = True  #: match again near where the last motion puts each keypoint
    guided_radius: float = 0.05  #: search radius around the predicted pixel, share of the smaller image side
    dense: bool = False  #: align the frames densely (Open3D RGB-D odometry), a low-trust prunable edge
    trust: float = 0.05  #: information of a dense edge relative to sparse inliers at the same points
    points: int = 300  #: verified points (evenly subsampled) that make its information
    max_step: float = 0.01  #: metres: a larger aligned motion between consecutive frames is rejected ...
    max_turn_deg: float = 15.0  #: ... as is a larger rotation (degrees)
    min_inlier_share: float = 0.6  #: of the frame's valid depth pixels that must land on the previous frame ...
    max_depth_residual: float = 0.05  #: ... with |depth difference| below this share of the depth ...
    max_photometric_rmse: float = 0.06  #: ... and an intensity RMSE (0..1 grey) below this
    #: place a frame that nothing linked where the camera's last motion puts it (constant velocity),
    #: checked on the same residuals, as a low-trust prunable edge
    bridge: bool = True
    bridge_max_frames: int = 1  #: consecutive frames a bridge may place (then the track breaks)
    bridge_window: int = 4  #: the velocity is the mean over this many last links in a row
    #: a bridge's own residual bounds (share of depth pixels landing on the previous frame's depth,
    #: intensity RMSE 0..1): a fold sweeping through the view fails the dense ones even at the true
    #: pose, while a cut to another place of the colon lands under 0.3 (docs/design.md)
    bridge_min_inlier_share: float = 0.45
    bridge_max_photometric_rmse: float = 0.1  #: see bridge_min_inlier_share

    def __post_init__(self) -> None:
        check(0 < self.guided_radius <= 1, f"fallback.guided_radius must be in (0, 1], got {self.guided_radius}")
        check(0 < self.trust <= 1, f"fallback.trust must be in (0, 1], got {self.trust}")
        at_least(self.points, 6, "fallback.points")
        check(self.max_step > 0 and 0 < self.max_turn_deg <= 180,
               f"fallback.max_step must be > 0 (metres) and fallback.max_turn_deg in (0, 180], "
               f"got {self.max_step}, {self.max_turn_deg}")
        at_least(self.bridge_max_frames, 1, "fallback.bridge_max_frames")
        at_least(self.bridge_window, 1, "fallback.bridge_window")
        check(0 < self.bridge_min_inlier_share <= 1 and self.bridge_max_photometric_rmse > 0,
               "fallback.bridge_min_inlier_share must be in (0, 1] and fallback.bridge_max_photometric_rmse > 0, "
               f"got {self.bridge_min_inlier_share}, {self.bridge_max_photometric_rmse}")
        check(0 < self.min_inlier_share <= 1 and self.max_depth_residual > 0 and self.max_photometric_rmse > 0,
               "fallback.min_inlier_share must be in (0, 1], fallback.max_depth_residual and "
               f"fallback.max_photometric_rmse > 0, got {self.min_inlier_share}, {self.max_depth_residual}, "
               f"{self.max_photometric_rmse}")
