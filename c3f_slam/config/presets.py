"""The runtime's presets, complete :class:`~c3f_slam.config.tree.SlamConfig` instances in one place.

- ``colon`` (the default): millimetre scale, the paper's rules for the colon (the dataclasses'
  defaults; the reasons for each value are in their docstrings and docs/design.md).
- ``room``: centimetre scale, for RGB-D indoor scenes (a room, a desk) as in Open3D's
  reconstruction system and BundleFusion: the match filter takes BundleFusion's values (2 cm
  residual, 0.032 m^2 area), the pose graph distrusts edges from 7 cm (Open3D's 1.4 x 5 cm voxels),
  TSDF voxels are 1 cm with 4 cm truncation up to 4 m, keyframe candidates lie within 1 m
  instead of 2 cm, reuse and fallback motions are scaled alike, dense refinement uses 8, 4, 2 cm
  voxels, and there is no unseen-wall estimate
  (the wall model is a tube's).

:data:`PAPER_RULES` restores the paper's literal rules at any map size: every new keyframe
matched against all keyframes, all its accepted matches kept, the whole component optimised
after every loop or merge (quadratic on long sequences), every fragment's first frame a keyframe.
"""

from __future__ import annotations

from collections.abc import Mapping
from types import MappingProxyType
from typing import Any

from c3f_core.settings import tree_from_mapping
from c3f_slam.config.checks import check
from c3f_slam.config.mapping import CandidateConfig, KeyframeConfig, PoseGraphConfig, RefineConfig
from c3f_slam.config.outputs import CoverageConfig, FusionConfig, TSDFConfig
from c3f_slam.config.tracking import FallbackConfig, MatchFilterConfig, RejoinConfig
from c3f_slam.config.tree import PRESET_NAMES, SlamConfig

COLON = SlamConfig()

ROOM = SlamConfig(
    preset="room",
    match_filter=MatchFilterConfig(max_residual=0.02, pairwise_tolerance=0.04, pairwise_relative_tolerance=0.05,
                                   min_area=0.032),
    candidates=CandidateConfig(spatial_radius=1.0),
    keyframes=KeyframeConfig(reuse_max_offset=0.25),
    rejoin=RejoinConfig(relaxed_max_step=0.05),
    fallback=FallbackConfig(max_step=0.1),
    refine=RefineConfig(voxels=(0.08, 0.04, 0.02), max_correction=0.1),
    posegraph=PoseGraphConfig(max_correspondence_distance=0.07),
    fusion=FusionConfig(tsdf=TSDFConfig(voxel_size=0.01, trunc=0.04, depth_min=0.1, depth_max=4.0,
                                                      block_resolution=16, block_count=10_000)),
    coverage=CoverageConfig(enabled=False),
)

#: every preset by name (read-only)
PRESETS: MappingProxyType[str, SlamConfig] = MappingProxyType({"colon": COLON, "room": ROOM})
assert tuple(PRESETS) == PRESET_NAMES

#: overrides (parts as dicts) that restore the paper's literal rules (see the module notes)
PAPER_RULES: dict[str, dict[str, Any]] = {
    "candidates": {"max_candidates": None},
    "keyframes": {"max_loop_edges": None, "reuse": False},
    "optimization": {"growth": None, "max_nodes": None, "final_nodes": None},
}


def preset(name: str = "colon", **overrides: Any) -> SlamConfig:
    """The preset ``name`` with ``overrides`` (top-level fields, or parts as dicts of fields);
    InputError naming the choices for an unknown name."""
    check(name in PRESETS, f"preset must be one of {tuple(PRESETS)}, got {name!r}")
    return PRESETS[name].with_(**overrides) if overrides else PRESETS[name]


def config_from_dict(data: Mapping[str, Any]) -> SlamConfig:
    """The tree of :meth:`SlamConfig.as_dict`'s form (a run's summary.json ``config``): ``data``,
    complete or partial, over the preset it names (``preset``, default colon); InputError for an
    unknown key or a bad value."""
    check(isinstance(data, Mapping), f"expected a mapping of settings, got {type(data).__name__}")
    return tree_from_mapping(preset(str(data.get("preset", "colon"))), data)


__all__ = ["PAPER_RULES", "PRESETS", "config_from_dict", "preset"]
