"""Settings of the SLAM runtime (docs/design.md, SLAM runtime), grouped by the part that reads them, with presets.

All lengths are metres, angles degrees. :class:`SlamConfig` holds one small frozen dataclass
per part: ``frontend`` (keypoints, ratio test), ``fragments`` (the new-fragment rule),
``candidates`` (:mod:`c3f_slam.pipeline.retrieval`), ``keyframes`` (what a keyframe keeps,
revisits: :mod:`c3f_slam.pipeline.reuse`), ``rejoin`` (bridging tracking breaks:
:mod:`c3f_slam.pipeline.rejoin`), ``fallback`` (guided and dense matching where sparse
matching fails: :mod:`c3f_slam.pipeline.fallback`), ``components`` (the components written
beside the main map:
:mod:`c3f_slam.pipeline.components`), ``optimization`` (the global schedule:
:mod:`c3f_slam.pipeline.schedule`), ``fusion``, ``coverage`` (the unseen-surface estimate:
:mod:`c3f_slam.coverage`), plus the match filter and pose-graph
settings of :mod:`c3f_slam.matching` and :mod:`c3f_slam.posegraph`. Each part validates
its own fields (:class:`InputError` naming ``part.field``). ``colon`` (default) and
``room`` pick the presets; the fragment rules are the paper's (85 % frustum overlap, 100
correspondences at 512 x 512 scaled with the frame's pixel count, resolved for a run by
:meth:`SlamConfig.for_frame_size`) unless overridden.

Overrides name a part and its fields, as a dict merged into the preset's part::

    SlamConfig.preset_config("colon", fragments={"min_correspondences": 15}, fusion={"enabled": False})
    cfg.with_(blas_threads=None, keyframes={"reuse": False})
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, fields, is_dataclass, replace
from typing import Any

from c3f_slam.coverage.config import CoverageConfig
from c3f_slam.errors import InputError
from c3f_slam.fusion import TSDF_PRESETS, TSDFConfig
from c3f_slam.matching import MatchFilterConfig
from c3f_slam.pipeline.retrieval import CandidateConfig
from c3f_slam.posegraph import POSEGRAPH_PRESETS, PoseGraphConfig

PRESETS = ("colon", "room")
#: the paper's new-fragment rule (docs/design.md, Fragments and keyframes) is for 512 x 512 frames
PAPER_MIN_CORRESPONDENCES, PAPER_FRAME_PIXELS = 100, 512 * 512
MODES = ("full", "odometry")


def _check(ok: bool, message: str) -> None:
    if not ok:
        raise InputError(message)


def _at_least(value: float | None, low: float, name: str, none: str = "") -> None:
    """InputError unless ``value`` is None or >= ``low``; ``none`` says what None means."""
    _check(value is None or value >= low, f"{name} must be >= {low}{f' (or None: {none})' if none else ''}, "
                                          f"got {value}")


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
        _at_least(self.max_keypoints, 10, "frontend.max_keypoints")
        _check(self.ratio is None or 0 < self.ratio <= 1, f"frontend.ratio must be in (0, 1] or None, got {self.ratio}")


@dataclass(frozen=True)
class FragmentConfig:
    """When a frame opens a new fragment (:func:`c3f_slam.pipeline.fragments.new_fragment_reason`)."""

    #: fewer filtered correspondences to the previous frame: new fragment. None: derived from the
    #: frame size (:meth:`correspondences_for`; the paper's 100 at 512 x 512)
    min_correspondences: int | None = None
    min_overlap: float = 0.85  #: lower frustum overlap with the active keyframe: new fragment
    overlap_stride: int = 4  #: pixel grid of the overlap test
    max_frames: int = 60  #: fragment length cap (memory)
    intra_all_pairs: bool = True  #: also match each frame to every frame of its fragment

    def __post_init__(self) -> None:
        _at_least(self.min_correspondences, 0, "fragments.min_correspondences", "from the frame size")
        _check(0.0 <= self.min_overlap <= 1.0, f"fragments.min_overlap must be in [0, 1], got {self.min_overlap}")
        _at_least(self.overlap_stride, 1, "fragments.overlap_stride")
        _at_least(self.max_frames, 1, "fragments.max_frames")

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
class KeyframeConfig:
    """What a keyframe keeps and adds to the global graph, and revisits (:mod:`c3f_slam.pipeline.reuse`)."""

    keypoints: int = 1000  #: features a keyframe keeps for global matching (compact copies)
    #: keyframe-match (loop) edges a new keyframe adds (:func:`cap_keyframe_edges`); None = all (the paper)
    max_loop_edges: int | None = 8
    reuse: bool = True  #: a fragment that revisits a mapped place hangs off that place's keyframe
    reuse_max_offset: float = 0.005  #: metres: a reuse must agree with the odometry link this well ...
    reuse_max_angle_deg: float = 10.0  #: ... and within this angle
    cache: bool = True  #: stored features on disk under OUT/.keyframe_cache (same results, flat RAM)

    def __post_init__(self) -> None:
        _at_least(self.keypoints, 10, "keyframes.keypoints")
        _at_least(self.max_loop_edges, 0, "keyframes.max_loop_edges", "keep all")
        _check(self.reuse_max_offset >= 0 and 0 <= self.reuse_max_angle_deg <= 180,
               "keyframes.reuse_max_offset must be >= 0 (metres) and keyframes.reuse_max_angle_deg in [0, 180], "
               f"got {self.reuse_max_offset}, {self.reuse_max_angle_deg}")


@dataclass(frozen=True)
class RejoinConfig:
    """How tracking breaks are bridged (:mod:`c3f_slam.pipeline.rejoin`; frames = processed frames)."""

    enabled: bool = True  #: try to join the frames after a break to the frames before it
    tail_frames: int = 6  #: frames before a break kept as targets (the last ones, every ``tail_step``-th)
    tail_step: int = 3  #: spacing of the kept tail frames
    window: int = 300  #: frames after a break during which its tail is tried (then it is dropped)
    keypoints: int = 500  #: features a tail frame keeps (strongest first)
    max_pending: int = 4  #: breaks remembered at once (the oldest is dropped)
    #: for the first ``relaxed_frames`` frames after a break, a tail frame the normal filter does not
    #: link is matched again accepting ``relaxed_min_matches`` correspondences (0 = off), if the
    #: motion it gives is one the camera can make in the frames between: at most ``relaxed_max_step``
    #: metres and ``relaxed_max_turn_deg`` degrees per frame
    relaxed_min_matches: int = 8
    relaxed_frames: int = 10
    relaxed_max_step: float = 0.003
    relaxed_max_turn_deg: float = 6.0

    def __post_init__(self) -> None:
        for name in ("tail_frames", "tail_step", "window", "keypoints", "max_pending"):
            _at_least(getattr(self, name), 1, f"rejoin.{name}")
        _check(self.relaxed_min_matches == 0 or self.relaxed_min_matches >= 6,
               f"rejoin.relaxed_min_matches must be 0 (off) or >= 6, got {self.relaxed_min_matches}")
        _at_least(self.relaxed_frames, 1, "rejoin.relaxed_frames")
        _check(self.relaxed_max_step > 0 and 0 < self.relaxed_max_turn_deg <= 180,
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
    residual checks (benchmarks/results/slam_tracking.md).
    """

    guided: bool = True
    guided_radius: float = 0.05  #: search radius around the predicted pixel, share of the smaller image side
    dense: bool = False
    trust: float = 0.05  #: information of a dense edge relative to sparse inliers at the same points
    points: int = 300  #: verified points (evenly subsampled) that make its information
    max_step: float = 0.01  #: metres: a larger aligned motion between consecutive frames is rejected ...
    max_turn_deg: float = 15.0  #: ... as is a larger rotation (degrees)
    min_inlier_share: float = 0.6  #: of the frame's valid depth pixels that must land on the previous frame ...
    max_depth_residual: float = 0.05  #: ... with |depth difference| below this share of the depth ...
    max_photometric_rmse: float = 0.06  #: ... and an intensity RMSE (0..1 grey) below this

    def __post_init__(self) -> None:
        _check(0 < self.guided_radius <= 1, f"fallback.guided_radius must be in (0, 1], got {self.guided_radius}")
        _check(0 < self.trust <= 1, f"fallback.trust must be in (0, 1], got {self.trust}")
        _at_least(self.points, 6, "fallback.points")
        _check(self.max_step > 0 and 0 < self.max_turn_deg <= 180,
               f"fallback.max_step must be > 0 (metres) and fallback.max_turn_deg in (0, 180], "
               f"got {self.max_step}, {self.max_turn_deg}")
        _check(0 < self.min_inlier_share <= 1 and self.max_depth_residual > 0 and self.max_photometric_rmse > 0,
               "fallback.min_inlier_share must be in (0, 1], fallback.max_depth_residual and "
               f"fallback.max_photometric_rmse > 0, got {self.min_inlier_share}, {self.max_depth_residual}, "
               f"{self.max_photometric_rmse}")


@dataclass(frozen=True)
class RefineConfig:
    """Dense refinement of keyframe-to-keyframe edges with Open3D's coloured ICP
    (:mod:`c3f_slam.pipeline.refine`). Lengths in metres: ``voxels`` coarse to fine (the
    preset's scale: room cm, colon mm), one ICP per voxel size with ``iterations`` each. Off by
    default for both presets: it did not lower the ATE on a synthetic room sequence nor on a
    simulator colon one (benchmarks/results/slam_dense_refine.md)."""

    enabled: bool = False  #: --dense-refine
    voxels: tuple[float, ...] = (0.002, 0.001, 0.0005)  #: voxel sizes, coarse to fine (metres)
    iterations: tuple[int, ...] = (30, 20, 10)  #: ICP iterations per voxel size
    max_correction: float = 0.005  #: metres: a refined pose further from the sparse one is rejected ...
    max_correction_deg: float = 5.0  #: ... as is a larger rotation between them (degrees)
    min_fitness: float = 0.5  #: share of the new keyframe's points within 1.5 voxels after refining
    min_gain: float = 0.02  #: the fitness must rise at least this much over the sparse pose's (0: any)
    max_edges: int = 4  #: edges refined per new keyframe (odometry first, then the strongest)
    cache: int = 64  #: keyframes whose clouds are kept (the most recent; older edges stay sparse)
    stride: int = 2  #: pixel grid of the keyframes' clouds

    def __post_init__(self) -> None:
        _check(len(self.voxels) >= 1 and len(self.voxels) == len(self.iterations)
               and all(v > 0 for v in self.voxels) and all(i >= 1 for i in self.iterations),
               f"refine.voxels and refine.iterations must be equally long, > 0, got {self.voxels}, {self.iterations}")
        _check(self.max_correction > 0 and 0 < self.max_correction_deg <= 180,
               "refine.max_correction must be > 0 (metres) and refine.max_correction_deg in (0, 180], "
               f"got {self.max_correction}, {self.max_correction_deg}")
        _check(0 <= self.min_fitness <= 1 and 0 <= self.min_gain <= 1,
               f"refine.min_fitness and refine.min_gain must be in [0, 1], got {self.min_fitness}, {self.min_gain}")
        for name in ("max_edges", "cache", "stride"):
            _at_least(getattr(self, name), 1, f"refine.{name}")

    @classmethod
    def room(cls) -> RefineConfig:
        """Room scale: 8, 4, 2 cm voxels; corrections up to 10 cm / 5 degrees."""
        return cls(voxels=(0.08, 0.04, 0.02), max_correction=0.1)


@dataclass(frozen=True)
class ComponentConfig:
    """What becomes of the components that could not be joined to the main map
    (:mod:`c3f_slam.pipeline.components`; frames = registered frames of a component)."""

    #: a component other than the main map with at least this many frames is optimised, fused
    #: and written to OUT/components/NN/; 0 = none is (``--component-min-frames``)
    min_frames: int = 30
    max_written: int = 8  #: at most this many of them, the largest ones

    def __post_init__(self) -> None:
        _at_least(self.min_frames, 0, "components.min_frames")
        _at_least(self.max_written, 0, "components.max_written")

    def writes(self, frames: int, rank: int) -> str | None:
        """Why a component with ``frames`` frames, the ``rank``-th largest besides the main map
        (from 1), is not written (None: it is)."""
        if self.min_frames <= 0:
            return "off"
        if frames < self.min_frames:
            return "below_min_frames"
        if rank > self.max_written:
            return "over_max_written"
        return None


@dataclass(frozen=True)
class OptimizationConfig:
    """When and how much of the global graph is optimised (:mod:`c3f_slam.pipeline.schedule`)."""

    every_keyframe: bool = True  #: after a keyframe that adds a loop or merges (False: only at the end)
    growth: float | None = 0.05  #: rate limit on big maps; None = after every such keyframe (the paper)
    small_map: int = 40  #: below this many keyframes every trigger optimises
    max_nodes: int | None = 100  #: bigger components are optimised in windows of this many; None = whole
    window_boundary_edges: int | None = 8  #: per window node, edges to fixed newer keyframes; None = all
    final_nodes: int | None = 600  #: at the end, whole up to this size, else one sweep of windows

    def __post_init__(self) -> None:
        _at_least(self.growth, 0, "optimization.growth", "after every keyframe")
        _at_least(self.window_boundary_edges, 0, "optimization.window_boundary_edges", "all")
        for name in ("max_nodes", "final_nodes"):
            _at_least(getattr(self, name), 2, f"optimization.{name}", "whole components")


@dataclass(frozen=True)
class FusionConfig:
    """TSDF fusion of settled fragments (:class:`c3f_slam.fusion.FragmentFusion`)."""

    enabled: bool = True  #: False = --no-mesh
    eps_f_na: int = 30  #: frames a fragment must be left behind before it is fused ...
    eps_cf_d: float = 0.05  #: ... and metres the camera must have moved away from it
    tsdf: TSDFConfig = field(default_factory=lambda: TSDF_PRESETS["colon"])  #: the volume


#: parts of :class:`SlamConfig` that overrides may give as dicts of their fields
SECTIONS = ("frontend", "fragments", "candidates", "keyframes", "rejoin", "fallback", "refine", "components",
            "optimization", "match_filter", "posegraph", "fusion", "coverage")

#: overrides that restore the paper's literal rules at any map size: every new keyframe matched
#: against all keyframes, all its accepted matches kept, the whole component optimised after
#: every loop or merge (quadratic on long sequences), every fragment's first frame a keyframe
PAPER_RULES: dict[str, dict[str, Any]] = {
    "candidates": {"max_candidates": None},
    "keyframes": {"max_loop_edges": None, "reuse": False},
    "optimization": {"growth": None, "max_nodes": None, "final_nodes": None},
}


@dataclass(frozen=True)
class SlamConfig:
    """Runtime options, one part per component (see the module notes)."""

    preset: str = "colon"  #: colon (mm scale) or room (cm scale)
    mode: str = "full"  #: full system, or the frame-to-frame odometry baseline
    frontend: FrontendConfig = field(default_factory=FrontendConfig)
    fragments: FragmentConfig = field(default_factory=FragmentConfig)
    candidates: CandidateConfig = field(default_factory=CandidateConfig)
    keyframes: KeyframeConfig = field(default_factory=KeyframeConfig)
    rejoin: RejoinConfig = field(default_factory=RejoinConfig)
    fallback: FallbackConfig = field(default_factory=FallbackConfig)
    refine: RefineConfig = field(default_factory=RefineConfig)  #: dense refinement of keyframe edges
    components: ComponentConfig = field(default_factory=ComponentConfig)
    optimization: OptimizationConfig = field(default_factory=OptimizationConfig)
    match_filter: MatchFilterConfig = field(default_factory=MatchFilterConfig.colon)
    posegraph: PoseGraphConfig = field(default_factory=lambda: POSEGRAPH_PRESETS["colon"])
    fusion: FusionConfig = field(default_factory=FusionConfig)
    coverage: CoverageConfig = field(default_factory=CoverageConfig)  #: the unseen-surface estimate at the end
    #: BLAS threads NumPy may use during a run (threadpoolctl); None = the library's setting.
    #: 1: the matrices are small (benchmarks/results/slam_blas_threads.md)
    blas_threads: int | None = 1

    def __post_init__(self) -> None:
        _check(self.preset in PRESETS, f"--preset must be one of {PRESETS}, got {self.preset!r}")
        _check(self.mode in MODES, f"--baseline/mode must be one of {MODES}, got {self.mode!r}")
        _at_least(self.blas_threads, 1, "blas_threads", "the BLAS library's default")
        for f in fields(self):  # parts given as dicts: merged into the part's defaults
            value = getattr(self, f.name)
            if f.name in SECTIONS and isinstance(value, dict):
                object.__setattr__(self, f.name, _merge_part(f.name, f.default_factory(), value))

    @classmethod
    def preset_config(cls, name: str = "colon", **overrides: Any) -> SlamConfig:
        """Defaults for ``colon`` (mm scale) or ``room`` (cm scale; fusion settles after 1 m,
        spatial keyframe candidates within 1 m instead of 2 cm, keyframe reuse within 25 cm
        of the odometry instead of 5 mm, no unseen-wall estimate: a room is no tube), with
        ``overrides`` (parts as dicts of fields)."""
        _check(name in PRESETS, f"--preset must be one of {PRESETS}, got {name!r}")
        room = name == "room"
        base = cls(
            preset=name,
            candidates=CandidateConfig(spatial_radius=1.0 if room else 0.02),
            keyframes=KeyframeConfig(reuse_max_offset=0.25 if room else 0.005),
            fallback=FallbackConfig(max_step=0.1 if room else 0.01),
            rejoin=RejoinConfig(relaxed_max_step=0.05 if room else 0.003),
            refine=RefineConfig.room() if room else RefineConfig(),
            match_filter=MatchFilterConfig.preset(name),
            posegraph=POSEGRAPH_PRESETS[name],
            fusion=FusionConfig(eps_cf_d=1.0 if room else 0.05, tsdf=TSDF_PRESETS[name]),
            coverage=CoverageConfig(enabled=not room),  # the wall model is a tube's
        )
        return base.with_(**overrides)

    def with_(self, **changes: Any) -> SlamConfig:
        """A copy with ``changes``: top-level fields, or parts as dicts merged into this one's."""
        known = {f.name for f in fields(self)}
        bad = sorted(set(changes) - known)
        _check(not bad, f"unknown SLAM option(s): {', '.join(bad)}")
        merged = {k: _merge_part(k, getattr(self, k), v) if k in SECTIONS and isinstance(v, dict) else v
                  for k, v in changes.items()}
        return replace(self, **merged)

    def for_frame_size(self, width: int, height: int) -> SlamConfig:
        """This config with the thresholds that derive from the frame size resolved
        (``fragments.min_correspondences``: :meth:`FragmentConfig.correspondences_for`)."""
        n = self.fragments.correspondences_for(width, height, self.match_filter.min_matches)
        return self.with_(fragments={"min_correspondences": n})

    def as_dict(self) -> dict:
        """Nested plain dict (summary.json's ``config``)."""
        return {f.name: asdict(v) if is_dataclass(v := getattr(self, f.name)) else v for f in fields(self)}


def _merge_part(name: str, part: Any, changes: dict[str, Any]) -> Any:
    """``part`` (a settings dataclass) with the fields in ``changes``; InputError for unknown ones."""
    known = {f.name for f in fields(part)}
    bad = sorted(set(changes) - known)
    _check(not bad, f"unknown SLAM option(s): {', '.join(f'{name}.{b}' for b in bad)}")
    return replace(part, **changes)
