"""The SLAM runtime's settings: one tree of small frozen dataclasses, its presets, and how a
run reads it (a config file, ``--set part.field=value``, a previous run's summary.json).

- :mod:`.tree`: :class:`SlamConfig`, the root;
- :mod:`.frames`: which frames are read, which carry nothing, the tissue area;
- :mod:`.tracking`: frontend, match filter, fragments, fallbacks, re-joining;
- :mod:`.mapping`: keyframe candidates, keyframes, dense refinement, pose graph, optimisation
  schedule, components;
- :mod:`.outputs`: TSDF fusion and the unseen-wall estimate;
- :mod:`.presets`: ``colon`` and ``room`` as complete instances, and the paper's literal rules;
- :mod:`.loading`: a tree from a preset, a YAML / JSON file and ``--set`` overrides, as YAML,
  and the help of every setting.

A leaf of the runtime: it imports only :mod:`c3f_core.errors` and :mod:`c3f_core.settings`
(and PyYAML when a file is read), so every part of the runtime and the layers above can use it.
"""

from c3f_slam.config.frames import FrameQualityConfig, FramesConfig, TissueConfig
from c3f_slam.config.mapping import (
    CandidateConfig,
    ComponentConfig,
    KeyframeConfig,
    OptimizationConfig,
    PoseGraphConfig,
    RefineConfig,
)
from c3f_slam.config.outputs import ChecksConfig, CoverageConfig, FusionConfig, TSDFConfig
from c3f_slam.config.presets import PAPER_RULES, PRESETS, config_from_dict, preset
from c3f_slam.config.tracking import (
    PAPER_FRAME_PIXELS,
    PAPER_MIN_CORRESPONDENCES,
    PREDICTED_DEPTH_RESIDUAL_SHARE,
    FallbackConfig,
    FragmentConfig,
    FrontendConfig,
    MatchFilterConfig,
    RejoinConfig,
)
from c3f_slam.config.tree import MODES, PRESET_NAMES, SECTIONS, SlamConfig

__all__ = [
    "CandidateConfig", "ChecksConfig", "ComponentConfig", "CoverageConfig", "FallbackConfig", "FragmentConfig",
    "FrameQualityConfig", "FramesConfig", "FrontendConfig", "FusionConfig", "KeyframeConfig", "MODES",
    "MatchFilterConfig", "OptimizationConfig", "PAPER_FRAME_PIXELS", "PAPER_MIN_CORRESPONDENCES", "PAPER_RULES",
    "PREDICTED_DEPTH_RESIDUAL_SHARE", "PRESETS", "PRESET_NAMES", "PoseGraphConfig", "RefineConfig",
    "RejoinConfig", "SECTIONS", "SlamConfig", "TSDFConfig", "TissueConfig", "config_from_dict", "preset",
]
