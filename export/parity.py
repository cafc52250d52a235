"""Parity of an exported graph: onnxruntime vs PyTorch on the same (real) frames.

The check runs after every export; the export fails loudly when the largest absolute
difference of any output element exceeds the tolerance (1e-4 by default: metres for depth
and pose translation, unit-vector components for descriptors).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import onnx
import onnxruntime as ort
import torch
from torch import nn


class ParityError(RuntimeError):
    """The ONNX graph's outputs differ from PyTorch's by more than the tolerance."""


@dataclass(frozen=True)
class ParityReport:
    """``max_abs_diff`` over ``frames`` inputs; ``ok`` when within ``tolerance``."""

    max_abs_diff: float
    mean_abs_diff: float
    tolerance: float
    frames: int

    @property
    def ok(self) -> bool:
        return bool(np.isfinite(self.max_abs_diff) and self.max_abs_diff <= self.tolerance)

    def as_dict(self) -> dict:
        return {"max_abs_diff": self.max_abs_diff, "mean_abs_diff": self.mean_abs_diff,
                "tolerance": self.tolerance, "frames": self.frames}


def ort_session(model: onnx.ModelProto | bytes | str, threads: int = 2) -> ort.InferenceSession:
    """A CPU onnxruntime session of a model proto, serialized bytes or file path."""
    opts = ort.SessionOptions()
    opts.intra_op_num_threads = threads
    opts.log_severity_level = 3
    src = model.SerializeToString() if isinstance(model, onnx.ModelProto) else model
    return ort.InferenceSession(src, opts, providers=["CPUExecutionProvider"])


def check_parity(
    module: nn.Module,
    model: onnx.ModelProto | bytes | str,
    inputs: tuple[torch.Tensor, ...],
    input_names: tuple[str, ...],
    tolerance: float = 1e-4,
    name: str = "graph",
) -> ParityReport:
    """Run both on ``inputs`` (one at a time along the batch, and as one batch); raise
    :class:`ParityError` above ``tolerance``."""
    module = module.eval().cpu()
    session = ort_session(model)
    with torch.no_grad():
        expected = module(*inputs).numpy()
    got = session.run(None, {n: x.numpy() for n, x in zip(input_names, inputs)})[0]
    if got.shape != expected.shape:
        raise ParityError(f"{name}: onnxruntime output shape {got.shape} != PyTorch {expected.shape}")
    diff = np.abs(got.astype(np.float64) - expected.astype(np.float64))
    report = ParityReport(float(diff.max()) if diff.size else 0.0, float(diff.mean()) if diff.size else 0.0,
                          float(tolerance), int(inputs[0].shape[0]))
    if not report.ok:
        raise ParityError(
            f"{name}: onnxruntime differs from PyTorch by {report.max_abs_diff:.3g} (max abs) on "
            f"{report.frames} frames, above the tolerance {tolerance:g}; the file was not written"
        )
    return report
