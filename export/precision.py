"""Lighter graphs: the float32 ONNX graph converted to float16 or int8 compute.

- ``float16``: every float32 weight and activation becomes float16
  (:func:`onnxruntime.transformers.float16.convert_float_to_float16`, which onnxruntime ships);
  inputs and outputs stay float32 (``keep_io_types``), so the runtime feeds and reads the file as
  any other. Meant for GPUs with fast half-precision arithmetic; on a CPU it is no faster.
- ``int8``: onnxruntime's static quantisation in QDQ form, weights int8 per output channel,
  activations uint8 with ranges calibrated on real training frames (MinMax over the
  ``calibration`` inputs); inputs and outputs stay float32. Convolutions run in int8 where the
  CPU has the instructions (VNNI): 1.3-1.8x faster than float32 at one thread for the zoo's nets
  on the project's 2-core machine (docs/export.md, Lighter models: float16 and int8).

The reduced precisions cannot meet the float32 parity tolerance (1e-4 absolute), so their parity
check compares the mean absolute difference to PyTorch's float32 output relative to the mean
magnitude of that output (:data:`RELATIVE_TOLERANCE`); the export records both numbers.
"""

from __future__ import annotations

import contextlib
import io
import logging
import tempfile
import warnings
from collections.abc import Iterator, Sequence
from pathlib import Path

import numpy as np
import onnx

from c3f_slam.models.metadata import PRECISIONS

#: graph inputs that are coordinates, not images: what depends on them stays float32
POINT_INPUTS = ("keypoints",)
#: default largest accepted mean |ONNX - PyTorch float32| / mean |PyTorch float32| per reduced precision
RELATIVE_TOLERANCE = {"float16": 5e-3, "int8": 6e-2}


def convert(model: onnx.ModelProto, precision: str,
            calibration: Sequence[dict[str, np.ndarray]] = ()) -> onnx.ModelProto:
    """``model`` (float32) in ``precision`` (:data:`PRECISIONS`); ``calibration``: the inputs
    (name -> array) whose activation ranges int8 quantisation uses (at least one)."""
    if precision not in PRECISIONS:
        raise ValueError(f"precision must be one of {PRECISIONS}, got {precision!r}")
    if precision == "float16":
        return to_float16(model)
    if precision == "int8":
        return to_int8(model, calibration)
    return model


def to_float16(model: onnx.ModelProto, keep_float32_from: Sequence[str] = POINT_INPUTS) -> onnx.ModelProto:
    """Float16 weights and arithmetic, float32 inputs and outputs; the nodes that depend on the
    inputs ``keep_float32_from`` stay float32 (:func:`downstream_nodes`)."""
    from onnxruntime.transformers.float16 import DEFAULT_OP_BLOCK_LIST, convert_float_to_float16

    with _quiet():
        half = convert_float_to_float16(model, keep_io_types=True, disable_shape_infer=True,
                                        op_block_list=list(DEFAULT_OP_BLOCK_LIST),
                                        node_block_list=downstream_nodes(model, keep_float32_from))
    return topologically_sorted(_without_input_round_trips(half))


def _without_input_round_trips(model: onnx.ModelProto) -> onnx.ModelProto:
    """Read the float32 graph inputs themselves where the converter cast one to float16 and
    straight back to float32 (it does so for the inputs of nodes kept float32: a rounding of the
    keypoints to float16 that nothing asked for); the casts no node reads any more are dropped."""
    graph = model.graph
    inputs = {i.name for i in graph.input}
    producer = {o: n for n in graph.node for o in n.output}
    to = {n.name: next((a.i for a in n.attribute if a.name == "to"), None) for n in graph.node if n.op_type == "Cast"}
    replace = {}
    for node in graph.node:
        first = producer.get(node.input[0]) if node.op_type == "Cast" and node.input else None
        if (to.get(node.name) == onnx.TensorProto.FLOAT and first is not None and first.op_type == "Cast"
                and to.get(first.name) == onnx.TensorProto.FLOAT16 and first.input[0] in inputs):
            replace[node.output[0]] = first.input[0]
    for node in graph.node:
        node.input[:] = [replace.get(i, i) for i in node.input]
    while True:  # drop the casts nothing reads (a dropped cast may leave its own input cast unread)
        used = {i for n in graph.node for i in n.input} | {o.name for o in graph.output}
        kept = [n for n in graph.node if n.op_type != "Cast" or any(o in used for o in n.output)]
        if len(kept) == len(graph.node):
            return model
        del graph.node[:]
        graph.node.extend(kept)


def downstream_nodes(model: onnx.ModelProto, inputs: Sequence[str]) -> list[str]:
    """Names of the top-level nodes that (indirectly) read any of the graph inputs ``inputs``: a
    keypoint graph's coordinate arithmetic, sampling and re-normalisation, which stay float32 in a
    float16 or int8 graph (pixel coordinates up to a few hundred need more than float16's 11 bits
    or uint8's 256 levels for sub-pixel positions)."""
    reached, names = set(inputs), []
    for node in model.graph.node:  # the exporter writes nodes in topological order
        if any(i in reached for i in node.input):
            reached.update(node.output)
            names.append(node.name)
    if any(not n for n in names):
        raise ValueError("a node downstream of the keypoints has no name; cannot keep it float32")
    return names


def topologically_sorted(model: onnx.ModelProto) -> onnx.ModelProto:
    """``model`` with its top-level nodes in an order where each node follows the producers of its
    inputs (the converter appends the input casts at the end; ONNX requires the order). Stable:
    nodes already in order keep it."""
    graph = model.graph
    ready = {i.name for i in graph.input} | {i.name for i in graph.initializer} | {""}
    pending, ordered = list(graph.node), []
    while pending:
        rest = []
        for node in pending:
            if all(name in ready for name in node.input):
                ordered.append(node)
                ready.update(node.output)
            else:
                rest.append(node)
        if len(rest) == len(pending):
            raise ValueError(f"graph has a cycle or an undefined input at node {rest[0].name}")
        pending = rest
    del graph.node[:]
    graph.node.extend(ordered)
    return model


class _Inputs:
    """onnxruntime's ``CalibrationDataReader`` protocol over a list of input dicts."""

    def __init__(self, inputs: Sequence[dict[str, np.ndarray]]) -> None:
        self._it: Iterator[dict[str, np.ndarray]] = iter(list(inputs))

    def get_next(self) -> dict[str, np.ndarray] | None:
        return next(self._it, None)


def to_int8(model: onnx.ModelProto, calibration: Sequence[dict[str, np.ndarray]],
            keep_float32_from: Sequence[str] = POINT_INPUTS) -> onnx.ModelProto:
    """Static QDQ int8 quantisation: int8 weights per channel, uint8 activations calibrated
    (MinMax) on ``calibration``; float32 inputs and outputs; the nodes that depend on the inputs
    ``keep_float32_from`` stay float32 (:func:`downstream_nodes`)."""
    from onnxruntime.quantization import CalibrationMethod, QuantFormat, QuantType, quantize_static
    from onnxruntime.quantization.shape_inference import quant_pre_process

    if not calibration:
        raise ValueError("int8 quantisation needs at least one calibration input")
    with tempfile.TemporaryDirectory(prefix="c3f-int8-") as tmp, _quiet():
        src, pre, out = (Path(tmp) / n for n in ("float32.onnx", "pre.onnx", "int8.onnx"))
        onnx.save_model(model, str(src))
        quant_pre_process(str(src), str(pre), skip_symbolic_shape=True)
        preprocessed = onnx.load_model(str(pre))
        quantize_static(str(pre), str(out), _Inputs(calibration), quant_format=QuantFormat.QDQ, per_channel=True,
                        activation_type=QuantType.QUInt8, weight_type=QuantType.QInt8,
                        calibrate_method=CalibrationMethod.MinMax,
                        nodes_to_exclude=downstream_nodes(preprocessed, keep_float32_from))
        return onnx.load_model(str(out))


@contextlib.contextmanager
def _quiet():
    """Silence the converters' warnings and prints (they report every node they keep in float)."""
    logger = logging.getLogger()
    level = logger.level
    logger.setLevel(logging.ERROR)
    try:
        with warnings.catch_warnings(), contextlib.redirect_stdout(io.StringIO()):
            warnings.simplefilter("ignore")
            yield
    finally:
        logger.setLevel(level)


__all__ = ["POINT_INPUTS", "PRECISIONS", "RELATIVE_TOLERANCE", "convert", "downstream_nodes", "to_float16",
           "to_int8", "topologically_sorted"]
