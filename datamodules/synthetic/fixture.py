"""Tiny simulated sequences for tests (a few seconds on a laptop CPU)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from datamodules.synthetic.generate import generate_sequence
from datamodules.synthetic.params import SimParams, apply_overrides

#: What makes a sequence tiny: a 15 cm colon, a coarse mesh and texture, no events.
TINY = {
    "colon.length": 0.15,
    "colon.ring_spacing": 0.001,
    "colon.ring_vertices": 96,
    "colon.polyps": 1,
    "appearance.texel": 0.0004,
    "path.kind": "A",
    "path.max_step": 0.004,
    "path.closeups": 0.0,
    "path.bursts": 0.0,
    "path.occlusions": 0.0,
    "path.roll_events": 0.0,
}


def tiny_params(frames: int = 8, size: int = 64, seed: int = 0, **overrides: Any) -> SimParams:
    """Parameters of a tiny sequence; ``overrides`` as in :func:`params.apply_overrides`
    (write dotted names as ``colon__fold_height=...`` or pass ``{"colon.fold_height": ...}``
    through ``**{...}``)."""
    base = SimParams(seed=seed, preset="tiny")
    merged = dict(TINY)
    merged.update({"path.frames": frames, "size": size})
    merged.update({k.replace("__", "."): v for k, v in overrides.items()})
    return apply_overrides(base, merged)


def make_tiny_sequence(out_dir: str | Path, frames: int = 8, size: int = 64, seed: int = 0, **overrides: Any) -> Path:
    """Write a tiny sequence (project layout, depth, poses, mesh) into ``out_dir``; returns it.

    The camera inserts along a 15 cm colon at about 4 mm per frame, well inside the lumen,
    so consecutive frames overlap strongly (suited to self-supervised depth tests).
    ``out_dir`` must not exist or be empty.
    """
    return generate_sequence(tiny_params(frames, size, seed, **overrides), out_dir, progress=False)
