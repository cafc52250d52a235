"""ONNX export of the trained networks (torch side; the runtime reads the files with
:mod:`c3f_slam.models`, never with torch).

- :func:`export_model`: checkpoint -> ONNX files with metadata and a parity check
  (``python -m c3f_models export --config ... --ckpt_path ...``).
- :mod:`export.graphs`: the exported graphs' inputs/outputs; :mod:`export.onnx_io`: the
  exporter call and atomic writing; :mod:`export.parity`: onnxruntime vs PyTorch.
"""

from export.exporter import export_model, load_checkpoint
from export.parity import ParityError, ParityReport, check_parity

__all__ = ["export_model", "load_checkpoint", "check_parity", "ParityError", "ParityReport"]
