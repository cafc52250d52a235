"""Tiny C3Fusion-style ONNX files built with ``onnx.helper`` (no torch), with closed forms.

- depth: ``depth = DEPTH_A + DEPTH_B * mean_c(image)`` (metres), (B, 1, H, W);
- descriptors: a fixed 1x1 convolution 3 -> ``dim`` (:func:`descriptor_weights`) followed by L2
  normalisation over channels, (B, dim, H, W); the keypoint variant samples that map at
  ``keypoints`` (B, N, 2) with ``GridSample`` (bilinear, border, align_corners) and normalises
  again, (B, N, dim);
- pose: the constant ``T_ba`` given, (B, 4, 4).

Inputs are (B, 3, H, W) float32 with H, W fixed to the metadata size unless ``dynamic``; the
metadata is written with :meth:`ModelMetadata.to_props` into ``model.metadata_props``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper

from c3f_slam.models.metadata import ModelMetadata, Preprocessing

OPSET = 18
IR_VERSION = 10
DEPTH_A, DEPTH_B = 0.01, 0.05  # metres: depth in [1, 6] cm


def _image_shape(size: tuple[int, int], dynamic: bool) -> list:
    w, h = size
    return ["batch", 3, "height", "width"] if dynamic else ["batch", 3, h, w]


def metadata(
    kind: str,
    size: tuple[int, int] = (32, 32),
    crop: tuple[int, int] | None = None,
    dynamic: bool = False,
    specular: bool = False,
    dim: int | None = None,
    **extra,
) -> ModelMetadata:
    """Metadata of a fixture model of ``kind`` (inputs/outputs as the exporter names them)."""
    image = {"shape": _image_shape(size, dynamic), "dtype": "float32", "meaning": "RGB in [0, 1]"}
    if kind == "pose":
        inputs = [{"name": "image_a", **image}, {"name": "image_b", **image}]
        outputs = [{"name": "T_ba", "shape": ["batch", 4, 4], "dtype": "float32", "units": "m",
                    "meaning": "frame-a camera coordinates into frame b"}]
    else:
        inputs = [{"name": "image", **image}]
        if kind == "depth":
            outputs = [{"name": "depth", "shape": ["batch", 1, "height", "width"], "dtype": "float32",
                        "units": "m", "meaning": "depth along the optical axis"}]
        elif extra.get("descriptor_sampling") == "keypoints":
            inputs.append({"name": "keypoints", "shape": ["batch", "keypoints", 2], "dtype": "float32",
                           "meaning": "(u, v) network-grid pixels"})
            outputs = [{"name": "descriptors", "shape": ["batch", "keypoints", dim], "dtype": "float32",
                        "units": "unit norm", "meaning": "descriptors at the keypoints"}]
        else:
            outputs = [{"name": "descriptors", "shape": ["batch", dim, "height", "width"], "dtype": "float32",
                        "units": "unit norm", "meaning": "dense descriptors"}]
    kw = dict(
        kind=kind, inputs=inputs, outputs=outputs,
        preprocessing=Preprocessing(size=tuple(size), crop=tuple(crop) if crop else None, specular_inpaint=specular),
        dynamic_size=dynamic, opset=OPSET,
        training_config={"model": {"backbone": "fixture", "lr": 1e-4}, "data": {"kind": "tiny"}},
        checkpoint={"file": "fixture.ckpt", "sha256": "0" * 64},
        parity={"max_abs_diff": 0.0, "tolerance": 1e-4, "frames": 2},
        project_version="test", created="2025-01-01T00:00:00Z",
    )
    if kind == "depth":
        kw["depth"] = {"min_depth": DEPTH_A, "max_depth": DEPTH_A + DEPTH_B, "conversion": "a + b * mean RGB"}
    if kind == "descriptors":
        kw["descriptor_dim"] = dim
    kw.update(extra)
    return ModelMetadata(**kw)


def _value(name: str, shape: list) -> onnx.ValueInfoProto:
    return helper.make_tensor_value_info(name, TensorProto.FLOAT, shape)


def _model(nodes, inputs, outputs, inits) -> onnx.ModelProto:
    graph = helper.make_graph(nodes, "c3f_fixture", inputs, outputs, initializer=inits)
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", OPSET)])
    model.ir_version = IR_VERSION
    onnx.checker.check_model(model)
    return model


def depth_graph(size=(32, 32), dynamic=False, output="depth") -> onnx.ModelProto:
    """depth = DEPTH_A + DEPTH_B * mean over RGB channels."""
    shape = _image_shape(size, dynamic)
    inits = [numpy_helper.from_array(np.array([1], np.int64), "axes"),
             numpy_helper.from_array(np.array(DEPTH_A, np.float32), "a"),
             numpy_helper.from_array(np.array(DEPTH_B, np.float32), "b")]
    nodes = [helper.make_node("ReduceMean", ["image", "axes"], ["m"], keepdims=1),
             helper.make_node("Mul", ["m", "b"], ["bm"]),
             helper.make_node("Add", ["bm", "a"], [output])]
    out_shape = [shape[0], 1, *shape[2:]]
    return _model(nodes, [_value("image", shape)], [_value(output, out_shape)], inits)


def descriptor_weights(dim: int = 8, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(dim, 3) weights and (dim,) bias of the fixture's 1x1 convolution."""
    rng = np.random.default_rng(seed)
    return rng.normal(size=(dim, 3)).astype(np.float32), rng.normal(scale=0.1, size=dim).astype(np.float32)


def descriptor_graph(size=(32, 32), dim: int = 8, dynamic=False, seed: int = 0) -> onnx.ModelProto:
    """Conv 1x1 (3 -> dim) then L2 normalisation over channels."""
    shape = _image_shape(size, dynamic)
    w, b = descriptor_weights(dim, seed)
    inits = [numpy_helper.from_array(w.reshape(dim, 3, 1, 1), "w"), numpy_helper.from_array(b, "bias")]
    nodes = [helper.make_node("Conv", ["image", "w", "bias"], ["f"], kernel_shape=[1, 1]),
             helper.make_node("LpNormalization", ["f"], ["descriptors"], axis=1, p=2)]
    return _model(nodes, [_value("image", shape)], [_value("descriptors", [shape[0], dim, *shape[2:]])], inits)


def keypoint_descriptor_graph(size=(32, 32), dim: int = 8, dynamic=False, seed: int = 0) -> onnx.ModelProto:
    """:func:`descriptor_graph`'s map sampled at ``keypoints`` (B, N, 2) pixels: grid = 2 u / (w - 1)
    - 1 (same for v), ``GridSample`` bilinear, border, align_corners, then L2 normalisation."""
    shape = _image_shape(size, dynamic)
    w, b = descriptor_weights(dim, seed)
    inits = [numpy_helper.from_array(w.reshape(dim, 3, 1, 1), "w"), numpy_helper.from_array(b, "bias"),
             numpy_helper.from_array(np.array([3, 2], np.int64), "wh_axes"),
             numpy_helper.from_array(np.array(1.0, np.float32), "one"),
             numpy_helper.from_array(np.array(2.0, np.float32), "two"),
             numpy_helper.from_array(np.array([2], np.int64), "grid_axis"),
             numpy_helper.from_array(np.array([3], np.int64), "last_axis")]
    nodes = [helper.make_node("Conv", ["image", "w", "bias"], ["f"], kernel_shape=[1, 1]),
             helper.make_node("LpNormalization", ["f"], ["m"], axis=1, p=2),
             helper.make_node("Shape", ["m"], ["shape"]),
             helper.make_node("Gather", ["shape", "wh_axes"], ["wh"]),  # (w, h)
             helper.make_node("Cast", ["wh"], ["whf"], to=TensorProto.FLOAT),
             helper.make_node("Sub", ["whf", "one"], ["wh1"]),
             helper.make_node("Div", ["two", "wh1"], ["scale"]),
             helper.make_node("Mul", ["keypoints", "scale"], ["g0"]),
             helper.make_node("Sub", ["g0", "one"], ["g1"]),
             helper.make_node("Unsqueeze", ["g1", "grid_axis"], ["grid"]),  # (B, N, 1, 2)
             helper.make_node("GridSample", ["m", "grid"], ["s"], mode="bilinear", padding_mode="border",
                              align_corners=1),  # (B, dim, N, 1)
             helper.make_node("Squeeze", ["s", "last_axis"], ["s2"]),
             helper.make_node("Transpose", ["s2"], ["s3"], perm=[0, 2, 1]),
             helper.make_node("LpNormalization", ["s3"], ["descriptors"], axis=2, p=2)]
    return _model(nodes, [_value("image", shape), _value("keypoints", [shape[0], "keypoints", 2])],
                  [_value("descriptors", [shape[0], "keypoints", dim])], inits)


def pose_graph(T_ba: np.ndarray, size=(32, 32), dynamic=False) -> onnx.ModelProto:
    """``T_ba`` for every batch item (the inputs only set the batch size)."""
    shape = _image_shape(size, dynamic)
    inits = [numpy_helper.from_array(np.asarray(T_ba, np.float32).reshape(1, 4, 4), "T"),
             numpy_helper.from_array(np.array([1, 2, 3], np.int64), "axes"),
             numpy_helper.from_array(np.array([-1, 1, 1], np.int64), "b11"),
             numpy_helper.from_array(np.array(0.0, np.float32), "zero")]
    nodes = [helper.make_node("Add", ["image_a", "image_b"], ["s"]),
             helper.make_node("ReduceSum", ["s", "axes"], ["r"], keepdims=0),  # (B,)
             helper.make_node("Reshape", ["r", "b11"], ["r11"]),  # (B, 1, 1)
             helper.make_node("Mul", ["r11", "zero"], ["z"]),
             helper.make_node("Add", ["z", "T"], ["T_ba"])]
    return _model(nodes, [_value("image_a", shape), _value("image_b", shape)],
                  [_value("T_ba", [shape[0], 4, 4])], inits)


def write(path: str | Path, model: onnx.ModelProto, meta: ModelMetadata | dict[str, str] | None) -> Path:
    """Save ``model`` with ``meta`` (metadata or raw props; None = no C3Fusion metadata)."""
    path = Path(path)
    model = onnx.ModelProto.FromString(model.SerializeToString())
    del model.metadata_props[:]
    props = meta.to_props() if isinstance(meta, ModelMetadata) else (meta or {})
    for k, v in props.items():
        entry = model.metadata_props.add()
        entry.key, entry.value = k, v
    onnx.save_model(model, str(path))
    return path


def depth_model(path, size=(32, 32), crop=None, dynamic=False, specular=False) -> Path:
    return write(path, depth_graph(size, dynamic), metadata("depth", size, crop, dynamic, specular))


def descriptor_model(path, size=(32, 32), crop=None, dim: int = 8, dynamic=False, specular=False) -> Path:
    meta = metadata("descriptors", size, crop, dynamic, specular, dim)
    return write(path, descriptor_graph(size, dim, dynamic), meta)


def keypoint_descriptor_model(path, size=(32, 32), crop=None, dim: int = 8, dynamic=False, specular=False,
                              **extra) -> Path:
    """The keypoint variant of :func:`descriptor_model` (same weights: same descriptors)."""
    meta = metadata("descriptors", size, crop, dynamic, specular, dim, descriptor_sampling="keypoints", **extra)
    return write(path, keypoint_descriptor_graph(size, dim, dynamic), meta)


def pose_model(path, T_ba: np.ndarray, size=(32, 32), crop=None) -> Path:
    return write(path, pose_graph(T_ba, size), metadata("pose", size, crop))
