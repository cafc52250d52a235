"""The runtime's settings tree: :class:`SlamConfig`, one small frozen group per part.

All lengths are metres, angles degrees. The parts: ``frames`` (which frames of the input are
read), ``tissue`` (the image area that shows tissue), ``frontend`` (keypoints, ratio test),
``match_filter``, ``fragments`` (the new-fragment rule), ``candidates`` (keyframe retrieval),
``keyframes`` (what a keyframe keeps, revisits), ``rejoin`` (bridging tracking breaks),
``fallback`` (guided and dense matching where sparse matching fails), ``refine`` (dense
refinement of keyframe edges), ``posegraph``, ``optimization`` (the global schedule),
``smoothing`` (the camera path on predicted depth), ``components`` (those written beside the
main map), ``fusion``, ``coverage`` (the unseen-wall estimate) and ``checks`` (the run's
agreement with itself, no ground truth). Each group validates its own fields (InputError naming
``part.field``). The presets are complete instances of this tree
(:mod:`c3f_slam.config.presets`); a run's ``summary.json`` records the tree it ran with
(:meth:`SlamConfig.as_dict`), and :func:`c3f_slam.config.presets.config_from_dict` reads it
back.

In Python, parts may be changed as dicts of their fields::

    preset("colon", fragments={"min_correspondences": 15}, fusion={"enabled": False})
    cfg.with_(blas_threads=None, keyframes={"reuse": False})
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, fields, replace
from typing import Any

from c3f_core.settings import tree_as_mapping, tree_from_mapping
from c3f_slam.config.checks import at_least, check
from c3f_slam.config.frames import FramesConfig, TissueConfig
from c3f_slam.config.mapping import (
    CandidateConfig,
    ComponentConfig,
    KeyframeConfig,
    OptimizationConfig,
    PoseGraphConfig,
    RefineConfig,
)
from c3f_slam.config.outputs import ChecksConfig, CoverageConfig, FusionConfig
from c3f_slam.config.smoothing import SmoothingConfig
from c3f_slam.config.tracking import FallbackConfig, FragmentConfig, FrontendConfig, MatchFilterConfig, RejoinConfig

PRESET_NAMES = ("colon", "room")
MODES = ("full", "odometry")


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
    smoothing: SmoothingConfig = field(default_factory=SmoothingConfig)
    components: ComponentConfig = field(default_factory=ComponentConfig)
    fusion: FusionConfig = field(default_factory=FusionConfig)
    coverage: CoverageConfig = field(default_factory=CoverageConfig)
    checks: ChecksConfig = field(default_factory=ChecksConfig)
    #: BLAS threads NumPy may use during a run (threadpoolctl); None = the library's setting.
    #: 1: the matrices are small (docs/design.md, Scaling to long sequences; measured in
    #: docs/lab_notes/2026-11-22-slam-blas-threads.md)
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
        :meth:`MatchFilterConfig.for_depth_source`; ``smoothing``: :meth:`SmoothingConfig.for_depth_source`)."""
        return replace(self, match_filter=self.match_filter.for_depth_source(depth_source),
                       smoothing=self.smoothing.for_depth_source(depth_source))

    def as_dict(self) -> dict:
        """The tree as nested plain dicts (summary.json's ``config``; ``config_from_dict`` reads it back)."""
        return tree_as_mapping(self)


#: the parts of :class:`SlamConfig` (the groups, in order)
SECTIONS = tuple(f.name for f in fields(SlamConfig) if f.name not in ("preset", "mode", "blas_threads"))
