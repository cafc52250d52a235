"""Tiny simulated sequences for tests (a few seconds on a laptop CPU): the ``tiny`` preset."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from c3f_core.settings import tree_from_mapping
from c3f_core.settings_cli import merge
from datamodules.synthetic.generate import generate_sequence
from datamodules.synthetic.params import SIM_SETTINGS, TINY, SimParams, parse_size

__all__ = ["TINY", "make_tiny_sequence", "tiny_params"]


def _nest(path: str, value: Any) -> dict[str, Any]:
    head, _, rest = path.partition(".")
    return {head: _nest(rest, value) if rest else value}


def tiny_params(frames: int = 8, size: int | str | tuple[int, int] = 64, seed: int = 0,
                **overrides: Any) -> SimParams:
    """The ``tiny`` preset (:data:`~datamodules.synthetic.params.TINY`: a 15 cm colon, no events)
    with ``frames``, ``size`` (pixels: N, ``"WxH"`` or (W, H)) and ``seed``; ``overrides`` set
    further fields by dotted name (pass ``**{"colon.fold_height": 0.4}`` or write
    ``colon__fold_height=0.4``), values as in ``--set``."""
    width, height = parse_size(size)
    changes: dict[str, Any] = {"seed": seed, "path": {"frames": frames}, "camera": {"width": width, "height": height}}
    for key, value in overrides.items():
        changes = merge(changes, _nest(key.replace("__", "."), value))
    return tree_from_mapping(SIM_SETTINGS.tree("tiny"), changes)


def make_tiny_sequence(out_dir: str | Path, frames: int = 8, size: int | str | tuple[int, int] = 64, seed: int = 0,
                       **overrides: Any) -> Path:
    """Write a tiny sequence (project layout, depth, poses, mesh) into ``out_dir``; returns it.

    The camera inserts along a 15 cm colon at about 4 mm per frame, well inside the lumen,
    so consecutive frames overlap strongly (suited to self-supervised depth tests).
    ``out_dir`` must not exist or be empty.
    """
    return generate_sequence(tiny_params(frames, size, seed, **overrides), out_dir, progress=False)
