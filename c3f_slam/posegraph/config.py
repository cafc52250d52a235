"""Resolving the pose-graph optimisation options of one call (the options themselves:
:class:`c3f_slam.config.PoseGraphConfig`, lengths in metres)."""

from __future__ import annotations

from dataclasses import replace

from c3f_slam.config import PoseGraphConfig


def resolve_config(config: PoseGraphConfig | None, overrides: dict[str, float]) -> PoseGraphConfig:
    """``config`` (default :class:`PoseGraphConfig`) with ``overrides`` replacing its fields
    (checked by the class: InputError, a ValueError, for a bad value)."""
    cfg = config or PoseGraphConfig()
    return replace(cfg, **overrides) if overrides else cfg
