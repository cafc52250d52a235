"""Seedable procedural colonoscopy simulator with exact ground truth (torch-free).

A smooth random colon (haustral folds, taeniae, polyps, relief) is built as a closed
triangle mesh; a camera path (insertion, withdrawal, random, loops, close-ups, bursts,
fold occlusions) is planned inside it; frames are ray cast with Open3D (exact depth) and
shaded like white-light colonoscopy (co-located light, wet highlights, vessels, vignetting,
bloom, grain). Same seed and parameters give byte-identical files.

    python -m datamodules.synthetic generate --preset seq1 --set seed=7 --set path.frames=300 \\
        --set camera.width=256 --set camera.height=256 --out DIR
    python -m datamodules.synthetic generate --preset seq1 --print-config   # every parameter
    python -m datamodules.synthetic contact-sheet DIR --out sheet.png

    from datamodules.synthetic import make_tiny_sequence   # tiny sequences for tests

Units are metres; angles in parameters are degrees; poses are camera-to-world.
Heavy modules (Open3D, OpenCV) load on first use of a name below.
"""

from __future__ import annotations

import importlib
from typing import Any

_EXPORTS = {
    "PRESETS": "params",
    "SIM_SETTINGS": "params",
    "SimParams": "params",
    "get_preset": "params",
    "build_scene": "scene",
    "generate_sequence": "generate",
    "render_frames": "scene",
    "read_event_labels": "generate",
    "make_tiny_sequence": "fixture",
    "tiny_params": "fixture",
    "make_contact_sheet": "contact_sheet",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    if name in _EXPORTS:
        return getattr(importlib.import_module(f"datamodules.synthetic.{_EXPORTS[name]}"), name)
    raise AttributeError(f"module 'datamodules.synthetic' has no attribute {name!r}")
