"""ONNX export of the trained networks (torch side; the runtime reads the files with
:mod:`c3f_slam.models`, never with torch).

- :func:`export_model`: checkpoint -> ONNX files with metadata and a parity check
  (``python -m c3f_models export --config ... --ckpt_path ...``); it names no model class.
- :mod:`export.graphs`: what a model exports (``GraphSpec``, the ``Exportable`` protocol the
  LightningModules follow); :mod:`export.onnx_io`: the exporter call and atomic writing;
  :mod:`export.parity`: onnxruntime vs PyTorch.

The package sits below :mod:`c3f_models` (the models import :mod:`export.graphs`, which is
light: the exporter, onnx and onnxruntime load on first use of the names below).
"""

from __future__ import annotations

import importlib
from typing import Any

_NAMES = {"export_model": "export.exporter", "check_parity": "export.parity", "ParityError": "export.parity",
          "ParityReport": "export.parity"}


def __getattr__(name: str) -> Any:
    if name in _NAMES:
        return getattr(importlib.import_module(_NAMES[name]), name)
    raise AttributeError(f"module 'export' has no attribute {name!r}")


__all__ = ["export_model", "check_parity", "ParityError", "ParityReport"]
