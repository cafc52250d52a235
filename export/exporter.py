"""Export a trained model's graphs to ONNX (DepthNet: depth + pose; ContraFeat: descriptors).

:func:`export_model` is what ``python -m c3f_models export`` runs (through
:meth:`c3f_models.trainer.C3FTrainer.export`). It names no model class: the model says what it
exports and loads its own checkpoint (:class:`export.graphs.Exportable`). It loads the
checkpoint into the model the config describes, exports each graph, check parity on real frames, and write
``OUTPUT_DIR/{depthnet,posenet,contrafeat,contrafeat_kp}.onnx`` plus ``export.json`` (files,
kinds, hashes, parity). A keypoint descriptor graph is also checked against the dense graph of
the same net sampled at the same keypoints by the runtime's rule
(:func:`export.parity.check_keypoint_sampling`). Nothing is written unless every graph of the
model passed its checks, and earlier files are replaced atomically.
"""

from __future__ import annotations

import datetime as _dt
import hashlib
import json
import os
import shutil
from collections.abc import Sequence as SequenceABC
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import onnx

from c3f_core.atomic import atomic_write_text, staging_dir
from c3f_core.errors import InputError
from c3f_slam import __version__
from c3f_slam.models.metadata import ModelMetadata, Preprocessing
from export.calibration import metric_scale as measure_metric_scale
from export.frames import calibration_images, frames_from_source, parity_source
from export.graphs import Exportable, GraphSpec
from export.onnx_io import STORAGE, store_float16, to_onnx, write_onnx
from export.parity import SAMPLING_TOLERANCE, check_keypoint_sampling, check_parity
from export.precision import PRECISIONS, RELATIVE_TOLERANCE, convert

#: the export's manifest (files, hashes, parity), moved into the output folder last
MANIFEST = "export.json"

def sha256(path: str | Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def graph_specs(model) -> list[GraphSpec]:
    """The graphs ``model`` exports (its :meth:`~export.graphs.Exportable.export_graphs`);
    InputError for a model that does not say."""
    if not isinstance(model, Exportable):
        raise InputError(f"model: {type(model).__name__} does not say what it exports (export_graphs, "
                         "load_export_checkpoint)")
    return model.export_graphs()


def selected_graphs(specs: list[GraphSpec], names: SequenceABC[str] | None) -> list[GraphSpec]:
    """The specs called ``names`` (:attr:`GraphSpec.name`; None: all); InputError naming
    ``--graphs`` for a name the model lacks."""
    if names is None:
        return specs
    have = [s.name for s in specs]
    unknown = [k for k in names if k not in have]
    if unknown or not names:
        raise InputError(f"--graphs: {unknown[0] if unknown else 'empty'}: this model exports {have}")
    return [s for s in specs if s.name in names]


def preprocessing_of(datamodule, source) -> Preprocessing:
    """Crop, size and inpainting the model was trained with (the data module's settings)."""
    hp = dict(getattr(datamodule, "hparams", {}) or {}).get("frames") or {}  # the data module's frames group
    crop = tuple(hp["crop"]) if hp.get("crop") else None
    size = hp.get("size")
    if size is None:  # training kept the (cropped) frame size
        cam = source.camera
        size = crop or (cam.width, cam.height)
    return Preprocessing(size=(int(size[0]), int(size[1])), crop=crop, specular_inpaint=bool(hp.get("specular", True)))


def _metric_scale(depth_graph, datamodule, pre: Preprocessing) -> dict | None:
    """:func:`export.calibration.metric_scale` on the data module's training sequences (None
    without a sequence data module or without true depth)."""
    if datamodule is None or not hasattr(datamodule, "split") or not hasattr(datamodule, "open_sequence"):
        return None
    paths = datamodule.split().get("train") or []
    return measure_metric_scale(depth_graph, [datamodule.open_sequence(p) for p in paths], pre,
                                names=[p.name for p in paths])


def _jsonable(obj) -> dict:
    """JSON-safe copy of hyper-parameters, without LightningCLI's private ``_*`` entries."""
    return json.loads(json.dumps({k: v for k, v in dict(obj).items() if not str(k).startswith("_")}, default=str))


KEYPOINTS_MEANING = "(u, v) network-grid pixels, pixel centres at integer coordinates"


def _io_entries(spec: GraphSpec, dynamic_size: bool) -> tuple[list[dict], list[dict]]:
    hw = ["height", "width"] if dynamic_size else None
    inputs = [{"name": n, "shape": ["batch", "keypoints", 2], "dtype": "float32", "meaning": KEYPOINTS_MEANING}
              if n in spec.point_inputs else
              {"name": n, "shape": ["batch", 3, *(hw or ["H", "W"])], "dtype": "float32",
               "meaning": "RGB in [0, 1] after the recorded preprocessing"} for n in spec.input_names]
    if spec.output_channels is None:
        shape = ["batch", 4, 4]
    elif spec.sampling == "keypoints":
        shape = ["batch", "keypoints", spec.output_channels]
    else:
        shape = ["batch", spec.output_channels, *(hw or ["H", "W"])]
    outputs = [{"name": spec.output_name, "shape": shape, "dtype": "float32", "units": spec.output_units,
                "meaning": spec.output_meaning}]
    return inputs, outputs


@dataclass
class _Provenance:
    """Where every exported graph comes from (recorded in its metadata and in export.json)."""

    training_config: dict  # model (and data module) class paths and init args
    checkpoint: dict  # {"file": name, "sha256": hex digest}
    created: str  # UTC time of the export, ISO 8601 to the second


def export_model(
    model: Exportable,
    ckpt_path: str | Path | None,
    output_dir: str | Path,
    *,
    datamodule=None,
    frames: str | Path | None = None,
    num_frames: int = 4,
    tolerance: float | None = None,
    dynamic_size: bool = True,
    weights_only: bool | None = None,
    graphs: SequenceABC[str] | None = None,
    storage: str = "float32",
    metric_scale: float | None = None,
    precision: str = "float32",
    calibration_frames: int = 32,
) -> list[Path]:
    """Export every graph of ``model`` (or those of ``graphs``) into ``output_dir``; returns the
    written files.

    Args:
        model: the configured model, e.g. DepthNet or ContraFeat (its weights are replaced by the
            checkpoint's; :class:`export.graphs.Exportable`).
        ckpt_path: Lightning checkpoint (or plain state dict) of that model.
        datamodule: the training data module (pre-processing settings; parity frames).
        frames: a sequence folder for the parity frames (default: the data module's).
        num_frames: frames in the parity check.
        tolerance: the parity bound: for float32 the largest accepted |onnxruntime - PyTorch| of
            any output element (None: 1e-4); for float16 and int8 the largest accepted mean
            absolute difference relative to the mean magnitude of PyTorch's float32 output
            (None: :data:`export.precision.RELATIVE_TOLERANCE`).
        dynamic_size: export height/width as dynamic axes.
        weights_only: accepted for the run's saved ``config.yaml``; checkpoints are always read with
            the safe unpickler (:func:`c3f_models.checkpoints.read_checkpoint_weights`), and False is refused.
        graphs: names of the graphs to export (DepthNet: ``depth``, ``pose``; ContraFeat:
            ``descriptors``, the dense map, and ``descriptors_kp``, descriptors at given keypoints);
            None: all of them.
        storage: ``float32``, or ``float16``: weights stored as float16 and cast to float32 when
            the file is loaded (half the size, float32 compute; :func:`export.onnx_io.store_float16`).
        metric_scale: record this factor to metres instead of measuring it on the training data
            (a network tuned without ground truth from one whose scale was measured, e.g. test-time
            training from a zoo model: give the zoo model's recorded scale).
        precision: the graphs' arithmetic: ``float32``, ``float16`` or ``int8``
            (:mod:`export.precision`; inputs and outputs stay float32).
        calibration_frames: training frames whose activation ranges int8 quantisation uses.
    """
    ckpt_path = _checked_arguments(ckpt_path, weights_only, num_frames)
    _check_encoding(storage, precision, tolerance, calibration_frames)
    if metric_scale is not None and not (np.isfinite(metric_scale) and metric_scale > 0):
        raise InputError(f"--metric_scale must be a positive number, got {metric_scale}")
    every = graph_specs(model)
    specs = selected_graphs(every, graphs)
    source = parity_source(frames, datamodule)  # bad paths fail before the slow steps
    model.load_export_checkpoint(ckpt_path, "--ckpt_path")
    pre = preprocessing_of(datamodule, source)
    images = frames_from_source(source, pre, num_frames)
    if tolerance is None:
        tolerance = 1e-4 if precision == "float32" else RELATIVE_TOLERANCE[precision]
    calibration = calibration_images(datamodule, source, pre, calibration_frames) if precision == "int8" else None
    encoding = _Encoding(storage, precision, tolerance, calibration)
    provenance = _Provenance(training_config=_training_config(model, datamodule),
                             checkpoint={"file": ckpt_path.name, "sha256": sha256(ckpt_path)},
                             created=_dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"))

    staged: list[tuple[GraphSpec, onnx.ModelProto, ModelMetadata]] = []
    for spec, proto, parity in _checked_graphs(specs, every, images, dynamic_size, encoding):
        depth = _depth_entry(spec, datamodule, pre, metric_scale) if spec.kind == "depth" else None
        staged.append((spec, proto, _graph_metadata(spec, pre, dynamic_size, depth=depth, parity=parity,
                                                    provenance=provenance, precision=precision)))
    return _write_export(staged, Path(output_dir), provenance)


def _check_encoding(storage: str, precision: str, tolerance: float | None, calibration: int) -> None:
    """InputError naming the option for an unknown storage or precision, float16 storage of a
    reduced-precision graph, a tolerance that is not positive, or int8 without calibration frames."""
    if storage not in STORAGE:
        raise InputError(f"--storage must be one of {', '.join(STORAGE)}, got {storage}")
    if precision not in PRECISIONS:
        raise InputError(f"--precision must be one of {', '.join(PRECISIONS)}, got {precision}")
    if precision != "float32" and storage != "float32":
        raise InputError(f"--storage {storage}: applies to --precision float32 only (a {precision} graph stores "
                         f"its weights in {precision} already)")
    if tolerance is not None and not (np.isfinite(tolerance) and tolerance > 0):
        raise InputError(f"--tolerance must be a positive number, got {tolerance}")
    if precision == "int8" and calibration < 1:
        raise InputError(f"--calibration_frames must be >= 1 for --precision int8, got {calibration}")


@dataclass(frozen=True)
class _Encoding:
    """How every graph of an export is written: weights ``storage`` (float32 graphs),
    arithmetic ``precision``, the parity ``tolerance`` and, for int8, the ``calibration`` frames
    (N, 3, h, w) of the training data."""

    storage: str
    precision: str
    tolerance: float
    calibration: object = None

    @property
    def criterion(self) -> str:
        """What the parity tolerance bounds (:class:`export.parity.ParityReport`)."""
        return "max_abs" if self.precision == "float32" else "relative_mean"


def _checked_graphs(specs: list[GraphSpec], every: list[GraphSpec], images, dynamic_size: bool,
                    encoding: _Encoding) -> list[tuple[GraphSpec, onnx.ModelProto, dict]]:
    """Each spec's ONNX model and parity entry, all exported and checked before anything is
    written (a keypoint graph also against its dense twin: ``parity.dense_sampling``)."""
    out, protos = [], {}
    for spec in specs:
        example = spec.example_inputs(images)
        protos[spec.name] = proto = _onnx_proto(spec, example, dynamic_size, encoding)
        parity = check_parity(spec.module, proto, example, spec.input_names, encoding.tolerance, name=spec.file_name,
                              criterion=encoding.criterion).as_dict()
        if spec.sampling == "keypoints":
            dense = _dense_twin(spec, every, protos, images, dynamic_size, encoding)
            parity["dense_sampling"] = check_keypoint_sampling(
                proto, dense, *example, name=spec.file_name,
                tolerance=SAMPLING_TOLERANCE if encoding.precision == "float32" else encoding.tolerance,
                criterion=encoding.criterion)
        if encoding.calibration is not None:
            parity["calibration_frames"] = int(encoding.calibration.shape[0])
        out.append((spec, proto, parity))
    return out


def _onnx_proto(spec: GraphSpec, example: tuple, dynamic_size: bool, encoding: _Encoding) -> onnx.ModelProto:
    """The ONNX model of ``spec`` traced on ``example``, in ``encoding``'s storage and precision."""
    proto = to_onnx(spec.module, example, spec.input_names, spec.output_name, spec.opset, dynamic_size=dynamic_size,
                    point_inputs=spec.point_inputs)
    if encoding.precision != "float32":
        calibration = ()
        if encoding.calibration is not None:
            inputs = spec.example_inputs(encoding.calibration)
            calibration = [{n: x[i:i + 1].numpy() for n, x in zip(spec.input_names, inputs)}
                           for i in range(inputs[0].shape[0])]
        return convert(proto, encoding.precision, calibration)
    return store_float16(proto) if encoding.storage == "float16" else proto


def _dense_twin(spec: GraphSpec, every: list[GraphSpec], protos: dict[str, onnx.ModelProto], images,
                dynamic_size: bool, encoding: _Encoding) -> onnx.ModelProto:
    """The dense descriptor graph of the model whose map keypoint graph ``spec`` samples: the one
    exported in this run, else exported now for the check only (not written)."""
    twin = next((s for s in every if s.kind == spec.kind and s.sampling == "dense"), None)
    if twin is None:
        raise InputError(f"model: its keypoint graph {spec.file_name} has no dense descriptor graph to check it "
                         "against")
    if twin.name not in protos:
        protos[twin.name] = _onnx_proto(twin, twin.example_inputs(images), dynamic_size, encoding)
    return protos[twin.name]


def _checked_arguments(ckpt_path: str | Path | None, weights_only: bool | None, num_frames: int) -> Path:
    """The checkpoint path; InputError (naming the option) for a missing checkpoint,
    ``weights_only`` False or fewer than one parity frame."""
    if ckpt_path is None:
        raise InputError("--ckpt_path: give the checkpoint to export")
    if weights_only is False:
        raise InputError("--weights_only false: refused; checkpoints are read with the safe loader only")
    ckpt_path = Path(ckpt_path)
    if num_frames < 1:
        raise InputError(f"--num_frames must be >= 1, got {num_frames}")
    return ckpt_path


def _training_config(model: Exportable, datamodule) -> dict:
    """Class paths and init args of the model and (if any) the data module, as a config records them."""
    config = {"model": {"class_path": f"{type(model).__module__}.{type(model).__name__}",
                        "init_args": _jsonable(model.hparams)}}
    if datamodule is not None:
        config["data"] = {"class_path": f"{type(datamodule).__module__}.{type(datamodule).__name__}",
                          "init_args": _jsonable(getattr(datamodule, "hparams", {}))}
    return config


def _depth_entry(spec: GraphSpec, datamodule, pre: Preprocessing, given_scale: float | None = None) -> dict:
    """The ``depth`` metadata of the depth graph: range (m), conversion, scale and the metric
    scale: ``given_scale``, else measured when the training data has true depth."""
    if spec.depth_range is None:
        raise InputError(f"model: its depth graph {spec.file_name} does not state its depth range")
    depth = {"min_depth": spec.depth_range[0], "max_depth": spec.depth_range[1],
             "conversion": "depth = 1 / (1/max_depth + (1/min_depth - 1/max_depth) * sigmoid_disparity), "
                           "in graph",
             "scale": "training scale (monocular depth: metres up to the scale the self-supervision fixed; "
                      "metric_scale, when present, is the factor to metres measured on the training data)"}
    if given_scale is not None:
        depth.update(metric_scale=float(given_scale),
                     metric_scale_source="given at export (--metric_scale), e.g. the scale of the model this one "
                                         "was tuned from without ground truth")
        return depth
    cal = _metric_scale(spec.module, datamodule, pre)
    if cal is not None:
        depth.update(metric_scale=cal["metric_scale"], metric_scale_spread=cal["spread"],
                     metric_scale_frames=cal["frames"], metric_scale_source=cal["source"])
    return depth


def _graph_metadata(spec: GraphSpec, pre: Preprocessing, dynamic_size: bool, *, depth: dict | None, parity: dict,
                    provenance: _Provenance, precision: str = "float32") -> ModelMetadata:
    """The metadata written into the graph's ONNX file."""
    inputs, outputs = _io_entries(spec, dynamic_size)
    return ModelMetadata(
        kind=spec.kind, inputs=inputs, outputs=outputs, preprocessing=pre, dynamic_batch=True,
        dynamic_size=dynamic_size, descriptor_dim=spec.output_channels if spec.kind == "descriptors" else None,
        descriptor_sampling=spec.sampling if spec.kind == "descriptors" else None, precision=precision, depth=depth,
        opset=spec.opset,
        training_config=provenance.training_config, checkpoint=provenance.checkpoint,
        parity=parity, project_version=__version__, created=provenance.created,
    )


def _write_export(staged: list[tuple[GraphSpec, onnx.ModelProto, ModelMetadata]], out: Path,
                  provenance: _Provenance) -> list[Path]:
    """Write the checked graphs and ``export.json`` (files, hashes, parity) into ``out``.

    Everything is written into a hidden folder beside ``out`` first, then moved in: ``out``'s
    old ``export.json`` goes first and the new one comes last, so an interrupted export leaves a
    folder without ``export.json`` (incomplete), never an old manifest beside new graphs.
    Other files in ``out`` are left alone.
    """
    if out.exists() and not out.is_dir():
        raise InputError(f"--output_dir: {out} exists and is not a folder")
    for spec, _, _ in staged:
        if (out / spec.file_name).is_dir():
            raise InputError(f"--output_dir: {out / spec.file_name} is a folder, expected an .onnx file path")
    tmp = staging_dir(out)
    try:
        files = [write_onnx(proto, meta, tmp / spec.file_name) for spec, proto, meta in staged]
        manifest = {
            "project_version": __version__, "created": provenance.created, "checkpoint": provenance.checkpoint,
            "files": {p.name: {"kind": m.kind, **({"descriptor_sampling": m.sampling} if m.sampling else {}),
                               "precision": m.precision, "sha256": sha256(p), "opset": m.opset, "parity": m.parity}
                      for p, (_, _, m) in zip(files, staged)},
        }
        atomic_write_text(tmp / MANIFEST, json.dumps(manifest, indent=2) + "\n")
        out.mkdir(parents=True, exist_ok=True)
        (out / MANIFEST).unlink(missing_ok=True)
        for path in [*files, tmp / MANIFEST]:
            os.replace(path, out / path.name)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return [out / p.name for p in files]
