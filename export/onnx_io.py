"""Run ``torch.onnx.export(dynamo=True)`` and write the file with its metadata, atomically.

The file is one self-contained ONNX model (no external data), opset 18, or 19 for graphs
with ``torchvision.ops.deform_conv2d`` (docs/design.md, Technical choices). Batch is always a
dynamic axis; height and width are dynamic when ``dynamic_size`` (the fully convolutional nets
allow it down to ``MIN_SIZE`` pixels, or the training size if smaller: the depth decoder pads its
coarsest (1/32) map by reflection); so is the number of points N of a (B, N, 2) keypoints input.
"""

from __future__ import annotations

import contextlib
import io
import warnings
from pathlib import Path

import numpy as np
import onnx
import torch
from torch import nn

from c3f_core.atomic import atomic_write
from c3f_core.errors import InputError
from c3f_slam.models.metadata import ModelMetadata

MIN_SIZE = 64
MAX_SIZE = 4096
MAX_POINTS = 1 << 20


def to_onnx(
    module: nn.Module,
    example: tuple[torch.Tensor, ...],
    input_names: tuple[str, ...],
    output_name: str,
    opset: int,
    *,
    dynamic_size: bool = True,
    point_inputs: tuple[str, ...] = (),
) -> onnx.ModelProto:
    """Export ``module`` (in eval mode, on CPU) and return the ONNX model proto. Inputs are
    (B, 3, H, W) images, except those named in ``point_inputs``: (B, N, 2) points, N dynamic
    (the example needs N >= 2).

    Raises RuntimeError with the exporter's reason when the graph cannot be exported.
    """
    module = module.eval().cpu()
    if example[0].shape[0] == 1:  # torch.export specialises size-1 axes: trace with a batch of 2
        example = tuple(torch.cat([x, x]) for x in example)
    batch = torch.export.Dim("batch", min=1, max=1024)
    axes: dict[int, object] = {0: batch}
    if dynamic_size:
        h, w = example[0].shape[-2:]
        axes[2] = torch.export.Dim("height", min=min(MIN_SIZE, int(h)), max=max(MAX_SIZE, int(h)))
        axes[3] = torch.export.Dim("width", min=min(MIN_SIZE, int(w)), max=max(MAX_SIZE, int(w)))
    points = {0: batch, 1: torch.export.Dim("keypoints", min=1, max=MAX_POINTS)}
    dynamic_shapes = tuple(dict(points if n in point_inputs else axes) for n in input_names)
    log = io.StringIO()
    try:
        with warnings.catch_warnings(), contextlib.redirect_stdout(log), torch.no_grad():
            warnings.simplefilter("ignore")
            program = torch.onnx.export(
                module, example, dynamo=True, external_data=False, opset_version=opset,
                input_names=list(input_names), output_names=[output_name], dynamic_shapes=dynamic_shapes,
                verbose=False, optimize=True,
            )
    except Exception as exc:  # the exporter's errors are long; keep the reason, point at the log
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise RuntimeError(f"ONNX export of {type(module).__name__} failed: {first}") from exc
    return program.model_proto


STORAGE = ("float32", "float16")


def store_float16(model: onnx.ModelProto, min_elements: int = 16) -> onnx.ModelProto:
    """``model`` with its float32 weights (initializers of at least ``min_elements``) stored as
    float16, each followed by a ``Cast`` back to float32: the file is about half as large and
    the computation stays float32 (onnxruntime folds the casts when it loads the model). Exact
    when the weights are float16 values already (the zoo's weights are); otherwise the parity
    check reports the rounding."""
    from onnx import TensorProto, helper, numpy_helper

    graph = model.graph
    kept, casts = [], []
    for init in graph.initializer:
        if init.data_type != TensorProto.FLOAT or int(np.prod(init.dims)) < min_elements:
            kept.append(init)
            continue
        half = numpy_helper.from_array(numpy_helper.to_array(init).astype(np.float16), init.name + "__f16")
        kept.append(half)
        casts.append(helper.make_node("Cast", [half.name], [init.name], to=TensorProto.FLOAT,
                                      name=init.name + "__to_f32"))
    del graph.initializer[:]
    graph.initializer.extend(kept)
    nodes = list(graph.node)
    del graph.node[:]
    graph.node.extend(casts + nodes)
    return model


def write_onnx(model: onnx.ModelProto, metadata: ModelMetadata, path: str | Path) -> Path:
    """Attach ``metadata`` as ``metadata_props``, check the model, write it atomically.

    An earlier file at ``path`` survives any failure.
    """
    path = Path(path)
    del model.metadata_props[:]
    for key, value in metadata.to_props().items():
        entry = model.metadata_props.add()
        entry.key, entry.value = key, value
    model.producer_name = "c3fusion"
    model.producer_version = metadata.project_version
    onnx.checker.check_model(model)
    if path.exists() and path.is_dir():
        raise InputError(f"--output_dir: {path} is a folder, expected an .onnx file path")
    with atomic_write(path) as tmp:
        onnx.save_model(model, str(tmp), save_as_external_data=False)
    return path
