"""Pose-graph optimisation options and their presets (lengths in metres)."""

from __future__ import annotations

from dataclasses import dataclass, replace


@dataclass(frozen=True)
class PoseGraphConfig:
    """Optimisation options; lengths in metres.

    - ``max_correspondence_distance``: the misalignment (RMS over an edge's points) at which
      an uncertain edge starts being distrusted; also the internal length unit.
    - ``edge_prune_threshold``: line-process confidence below which an uncertain edge is pruned.
    - ``preference_loop_closure``: weight of loop closures against odometry (larger keeps
      more loop edges).
    """

    max_correspondence_distance: float = 0.003
    edge_prune_threshold: float = 0.25
    preference_loop_closure: float = 1.0
    max_iterations: int = 100


#: Colon: 3 mm (a few voxels of the 1 mm TSDF, the size of DepthNet's depth noise at a few
#: cm). Room (RGB-D indoor scenes, Open3D's reconstruction system uses 1.4 x 5 cm voxels): 7 cm.
POSEGRAPH_PRESETS: dict[str, PoseGraphConfig] = {
    "colon": PoseGraphConfig(max_correspondence_distance=0.003),
    "room": PoseGraphConfig(max_correspondence_distance=0.07),
}


def resolve_config(config: PoseGraphConfig | None, overrides: dict[str, float]) -> PoseGraphConfig:
    """``config`` (default :class:`PoseGraphConfig`) with ``overrides`` replacing its fields;
    raises ValueError unless ``max_correspondence_distance`` is positive."""
    cfg = config or PoseGraphConfig()
    if overrides:
        cfg = replace(cfg, **overrides)
    if not cfg.max_correspondence_distance > 0:
        raise ValueError("max_correspondence_distance must be positive")
    return cfg
