"""Parity of an exported graph: onnxruntime vs PyTorch on the same (real) frames.

The check runs after every export; the export fails loudly when the largest absolute
difference of any output element exceeds the tolerance (1e-4 by default: metres for depth
and pose translation, unit-vector components for descriptors). A float16 or int8 graph
(:mod:`export.precision`) is held to a bound on its mean absolute difference relative to the
mean magnitude of PyTorch's float32 output instead. A keypoint descriptor graph is
also checked against the dense graph of the same net sampled by the runtime's rule
(:func:`check_keypoint_sampling`, 1e-5).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import onnx
import onnxruntime as ort
import torch
from torch import nn

from c3f_slam.matching.descriptors import sample_descriptor_map

#: largest accepted |keypoint graph - dense graph sampled by the runtime| (unit-vector components)
SAMPLING_TOLERANCE = 1e-5


class ParityError(RuntimeError):
    """The ONNX graph's outputs differ from PyTorch's by more than the tolerance."""


@dataclass(frozen=True)
class ParityReport:
    """Differences over ``frames`` inputs; ``ok`` when the ``criterion`` is within ``tolerance``:
    ``max_abs`` (the largest absolute difference of any element; float32 graphs) or
    ``relative_mean`` (mean absolute difference over the mean magnitude of PyTorch's output;
    float16 and int8 graphs, :mod:`export.precision`)."""

    max_abs_diff: float
    mean_abs_diff: float
    tolerance: float
    frames: int
    relative_mean_diff: float = 0.0
    criterion: str = "max_abs"

    @property
    def measured(self) -> float:
        """The number the tolerance bounds."""
        return self.relative_mean_diff if self.criterion == "relative_mean" else self.max_abs_diff

    @property
    def ok(self) -> bool:
        return bool(np.isfinite(self.max_abs_diff) and self.measured <= self.tolerance)

    def as_dict(self) -> dict:
        return {"max_abs_diff": self.max_abs_diff, "mean_abs_diff": self.mean_abs_diff,
                "relative_mean_diff": self.relative_mean_diff, "criterion": self.criterion,
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
    criterion: str = "max_abs",
) -> ParityReport:
    """Run both on ``inputs`` (as one batch); raise :class:`ParityError` when ``criterion``
    (:class:`ParityReport`) exceeds ``tolerance``."""
    module = module.eval().cpu()
    session = ort_session(model)
    with torch.no_grad():
        expected = module(*inputs).numpy()
    got = session.run(None, {n: x.numpy() for n, x in zip(input_names, inputs)})[0]
    if got.shape != expected.shape:
        raise ParityError(f"{name}: onnxruntime output shape {got.shape} != PyTorch {expected.shape}")
    diff = np.abs(got.astype(np.float64) - expected.astype(np.float64))
    mean = float(diff.mean()) if diff.size else 0.0
    scale = float(np.abs(expected).mean()) if expected.size else 0.0
    report = ParityReport(float(diff.max()) if diff.size else 0.0, mean, float(tolerance), int(inputs[0].shape[0]),
                          mean / scale if scale > 0 else mean, criterion)
    if not report.ok:
        what = "(max abs)" if criterion == "max_abs" else "(mean abs over the mean magnitude)"
        raise ParityError(
            f"{name}: onnxruntime differs from PyTorch by {report.measured:.3g} {what} on "
            f"{report.frames} frames, above the tolerance {tolerance:g}; the file was not written"
        )
    return report


def check_keypoint_sampling(
    keypoint_model: onnx.ModelProto | bytes | str,
    dense_model: onnx.ModelProto | bytes | str,
    images: torch.Tensor,
    keypoints: torch.Tensor,
    tolerance: float = SAMPLING_TOLERANCE,
    name: str = "graph",
    criterion: str = "max_abs",
) -> dict:
    """Compare, on onnxruntime, the keypoint graph's (B, N, C) descriptors with the dense graph's
    (B, C, H, W) map sampled at the same (B, N, 2) keypoints by the runtime's rule
    (:func:`c3f_slam.matching.sample_descriptor_map`: bilinear, clamped, re-normalised). Returns
    the entry recorded in the parity metadata (``dense_sampling``); :class:`ParityError` when
    ``criterion`` (:class:`ParityReport`) exceeds ``tolerance``."""
    x, kp = images.numpy(), keypoints.numpy()
    got = ort_session(keypoint_model).run(None, {"image": x, "keypoints": kp})[0]
    maps = ort_session(dense_model).run(None, {"image": x})[0]
    expected = np.stack([sample_descriptor_map(m, p, normalise=True) for m, p in zip(maps, kp)])
    if got.shape != expected.shape:
        raise ParityError(f"{name}: keypoint graph output shape {got.shape} != sampled dense map {expected.shape}")
    diff = np.abs(got.astype(np.float64) - expected.astype(np.float64))
    worst = float(diff.max()) if diff.size else 0.0
    mean = float(diff.mean()) if diff.size else 0.0
    scale = float(np.abs(expected).mean()) if expected.size else 0.0
    relative = mean / scale if scale > 0 else mean
    measured = relative if criterion == "relative_mean" else worst
    if not (np.isfinite(worst) and measured <= tolerance):
        what = "(max abs)" if criterion == "max_abs" else "(mean abs over the mean magnitude)"
        raise ParityError(
            f"{name}: the keypoint graph differs from the dense graph sampled at the same keypoints by "
            f"{measured:.3g} {what}, above the tolerance {tolerance:g}; the file was not written"
        )
    return {"max_abs_diff": worst, "mean_abs_diff": mean, "relative_mean_diff": relative, "criterion": criterion,
            "tolerance": float(tolerance), "frames": int(kp.shape[0]), "keypoints": int(kp.shape[1]),
            "reference": "the dense graph on onnxruntime, sampled by c3f_slam.matching.sample_descriptor_map"}
