"""The runtime's settings tree: :class:`SlamConfig`, one small frozen group per part.

All lengths are metres, angles degrees. The parts: ``frames`` (which frames of the input are
read), ``tissue`` (the image area that shows tissue), ``frontend`` (keypoints, ratio test),
``match_filter``, ``fragments`` (the new-fragment rule), ``candidates`` (keyframe retrieval),
``keyframes`` (what a keyframe keeps, revisits), ``rejoin`` (bridging tracking breaks),
``fallback`` (guided and dense matching where sparse matching fails), ``refine`` (dense
refinement of keyframe edges), ``posegraph``, ``optimization`` (the global schedule),
``components`` (those written beside the main map), ``fusion``, ``coverage`` (the unseen-wall
estimate) and ``checks`` (the run's agreement with itself, no ground truth). Each group
validates its own fields (InputError naming ``part.field``). The presets are complete instances
of this tree (:mod:`c3f_slam.config.presets`); a run's ``summary.json`` records the tree it ran
with (:meth:`SlamConfig.as_dict`), and :func:`c3f_slam.config.presets.config_from_dict` reads it
back.

In Python, parts may be changed as dicts of their fields::

    preset("colon", fragments={"min_correspondences": 15}, fusion={"enabled": False})
    cfg.with_(blas_threads=None, keyframes={"reuse": False})
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, fields, replace
from typing import Any

from c3f_slam.config.checks import at_least, check
from c3f_slam.config.mapping import (
    CandidateConfig,
    ComponentConfig,
    KeyframeConfig,
    OptimizationConfig,
    PoseGraphConfig,
    RefineConfig,
)
from c3f_slam.config.outputs import ChecksConfig, CoverageConfig, FusionConfig
from c3f_slam.config.tracking import FallbackConfig, FragmentConfig, FrontendConfig, MatchFilterConfig, RejoinConfig
from c3f_slam.settings import tree_as_mapping, tree_from_mapping

PRESET_NAMES = ("colon", "room")
MODES = ("full", "odometry")


@dataclass(frozen=True)
class FramesConfig:
    """Which frames of the input a run reads (frames of the sequence or video, in order), and
    how far ahead of the back-end they are read and perceived."""

    stride: int = 1  #: every k-th frame
    max_frames: int | None = None  #: at most this many of them; None = all
    #: frames read and perceived (depth, keypoints, descriptors) ahead of the back-end by a worker
    #: thread, overlapping it; 0 = one after another in the run loop. Same results either way
    prefetch: int = 2
    #: threads that perceive frames at once (with prefetch >= 1; at most prefetch + 1 are busy):
    #: the networks and SIFT of the next frames overlap each other as well as the back-end.
    #: Same results with any number
    perception_workers: int = 2

    def __post_init__(self) -> None:
        at_least(self.stride, 1, "frames.stride")
        at_least(self.max_frames, 1, "frames.max_frames", "all frames")
        at_least(self.prefetch, 0, "frames.prefetch")
        at_least(self.perception_workers, 1, "frames.perception_workers")


TISSUE_MODES = ("auto", "off")


@dataclass(frozen=True)
class TissueConfig:
    """The image area that shows tissue (:mod:`c3f_slam.tissue`): the scope's black border and
    burned-in overlays are left out of depth, keypoints, fusion and the unseen-wall estimate.
    Luma levels are 0..255."""

    #: auto: ``file``, else the mask camera.json names (``tissue_mask``), else detected from the
    #: first frames; off: the whole frame
    mode: str = "auto"
    file: str | None = None  #: mask image (PNG of the frame size, white = tissue); None: see ``mode``
    frames: int = 40  #: frames sampled for detection
    window: int = 300  #: ... evenly over the first this many frames of the run (5 s of 60 fps video)
    dark_level: float = 30.0  #: a pixel no sample shows brighter than this is border
    static_level: float = 3.0  #: a change of luma up to this between two samples is compression noise
    #: a pixel changing between at least this share of consecutive samples moves with the scene
    moving_share: float = 0.3
    overlay_edge: float = 120.0  #: Sobel magnitude of the temporal median at a static overlay's edge
    margin: float = 0.015  #: the mask is eroded by this share of the smaller image side
    full_share: float = 0.995  #: a mask covering at least this share of the frame: no border

    def __post_init__(self) -> None:
        check(self.mode in TISSUE_MODES, f"tissue.mode must be one of {TISSUE_MODES}, got {self.mode!r}")
        at_least(self.frames, 2, "tissue.frames")
        at_least(self.window, 2, "tissue.window")
        for name in ("dark_level", "static_level", "overlay_edge", "margin"):
            at_least(getattr(self, name), 0.0, f"tissue.{name}")
        check(0.0 < self.moving_share <= 1.0, f"tissue.moving_share must be in (0, 1], got {self.moving_share}")
        check(0.0 < self.full_share <= 1.0, f"tissue.full_share must be in (0, 1], got {self.full_share}")
        check(self.margin < 0.25, f"tissue.margin must be < 0.25, got {self.margin}")


@dataclass(frozen=True)
class SlamConfig:
    """Runtime settings, one group per part (see the module notes); the defaults are the
    ``colon`` preset."""

    preset: str = "colon"  #: the preset this tree started from: colon (mm scale) or room (cm scale)
    mode: str = "full"  #: full system, or the frame-to-frame odometry baseline (odometry)
    frames: FramesConfig = field(default_factory=FramesConfig)
    tissue: TissueConfig = field(default_factory=TissueConfig)
    frontend: FrontendConfig = field(default_factory=FrontendConfig)
    match_filter: MatchFilterConfig = field(default_factory=MatchFilterConfig)
    fragments: FragmentConfig = field(default_factory=FragmentConfig)
    candidates: CandidateConfig = field(default_factory=CandidateConfig)
    keyframes: KeyframeConfig = field(default_factory=KeyframeConfig)
    rejoin: RejoinConfig = field(default_factory=RejoinConfig)
    fallback: FallbackConfig = field(default_factory=FallbackConfig)
    refine: RefineConfig = field(default_factory=RefineConfig)
    posegraph: PoseGraphConfig = field(default_factory=PoseGraphConfig)
    optimization: OptimizationConfig = field(default_factory=OptimizationConfig)
    components: ComponentConfig = field(default_factory=ComponentConfig)
    fusion: FusionConfig = field(default_factory=FusionConfig)
    coverage: CoverageConfig = field(default_factory=CoverageConfig)
    checks: ChecksConfig = field(default_factory=ChecksConfig)
    #: BLAS threads NumPy may use during a run (threadpoolctl); None = the library's setting.
    #: 1: the matrices are small (benchmarks/results/slam_blas_threads.md)
    blas_threads: int | None = 1

    def __post_init__(self) -> None:
        check(self.preset in PRESET_NAMES, f"preset must be one of {PRESET_NAMES}, got {self.preset!r}")
        check(self.mode in MODES, f"mode must be one of {MODES}, got {self.mode!r}")
        at_least(self.blas_threads, 1, "blas_threads", "the BLAS library's default")
        for f in fields(self):  # parts given as dicts: merged into the part's defaults
            value = getattr(self, f.name)
            if f.name in SECTIONS and isinstance(value, Mapping):
                object.__setattr__(self, f.name, tree_from_mapping(f.default_factory(), value, f.name))

    def with_(self, **changes: Any) -> SlamConfig:
        """A copy with ``changes``: top-level fields, or parts as dicts merged into this one's
        (nested groups, e.g. ``fusion={"tsdf": {"voxel_size": 0.002}}``, merge too)."""
        return tree_from_mapping(self, changes)

    def for_frame_size(self, width: int, height: int) -> SlamConfig:
        """This config with the thresholds that derive from the frame size resolved
        (``fragments.min_correspondences``: :meth:`FragmentConfig.correspondences_for`)."""
        n = self.fragments.correspondences_for(width, height, self.match_filter.min_matches)
        return replace(self, fragments=replace(self.fragments, min_correspondences=n))

    def for_depth_source(self, depth_source: str) -> SlamConfig:
        """This config with the thresholds that derive from the depth source (``files`` |
        ``model``) resolved (``match_filter.residual_relative_tolerance``:
        :meth:`MatchFilterConfig.for_depth_source`)."""
        return replace(self, match_filter=self.match_filter.for_depth_source(depth_source))

    def as_dict(self) -> dict:
        """The tree as nested plain dicts (summary.json's ``config``; ``config_from_dict`` reads it back)."""
        return tree_as_mapping(self)


#: the parts of :class:`SlamConfig` (the groups, in order)
SECTIONS = tuple(f.name for f in fields(SlamConfig) if f.name not in ("preset", "mode", "blas_threads"))
