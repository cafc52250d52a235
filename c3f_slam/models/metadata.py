"""The metadata that travels inside every exported ONNX file (``metadata_props``).

Written by :mod:`export` (torch side), read by :mod:`c3f_slam.models` (runtime, no torch);
this module is the one definition of the schema. Every field is stored under its own key
``c3f.<field>`` with a JSON value, so ``onnx.load(path).metadata_props`` stays readable.

Conventions recorded here and relied on by the runtime:

- Inputs are NCHW float32 RGB in [0, 1] at ``preprocessing.size`` (width, height), after the
  training pre-processing (:func:`c3f_slam.frames.preprocess.prepare_network_input`: centre crop,
  resize, specular inpainting). ImageNet normalisation is inside the graph
  (``preprocessing.normalization_in_graph``); the mean/std are recorded for reference.
- ``depth`` models output depth in metres (B, 1, H, W); the sigmoid disparity -> depth
  conversion is inside the graph and recorded in ``depth.conversion``.
- ``descriptors`` models output unit-norm descriptors, C = ``descriptor_dim``; how is
  ``descriptor_sampling``: ``dense`` (absent in files written before the field existed): the map
  (B, C, H, W) from ``image``; ``keypoints``: (B, N, C) at ``keypoints`` (B, N, 2) float32 (u, v)
  in network-grid pixels (pixel centres at integer coordinates), sampled inside the graph by the
  rule of :func:`c3f_slam.matching.sample_descriptor_map` (bilinear, clamped at the border,
  re-normalised).
- ``precision``: the arithmetic of the graph: ``float32`` (absent in files written before the
  field existed), ``float16`` or ``int8`` (weights int8, activations uint8 in QDQ form); inputs
  and outputs are float32 in every precision.
- ``pose`` models take two frames (earlier first) and output ``T_ba`` (B, 4, 4): frame-a
  camera coordinates into frame b, metres.

Bump :data:`SCHEMA_VERSION` when a field changes meaning; readers refuse newer files.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field, fields
from typing import Any

from c3f_core.errors import InputError
from c3f_slam.frames.preprocess import IMAGENET_MEAN, IMAGENET_STD, SPECULAR_DILATION_PX, SPECULAR_THRESHOLD

SCHEMA_VERSION = 1
KINDS = ("depth", "pose", "descriptors")
#: how a descriptors model samples: its dense map, or at given keypoints inside the graph
SAMPLINGS = ("dense", "keypoints")
#: a graph's arithmetic (:mod:`export.precision`); inputs and outputs are float32 in each
PRECISIONS = ("float32", "float16", "int8")
KEY_PREFIX = "c3f."
REQUIRED = ("kind", "inputs", "outputs", "preprocessing")


@dataclass(frozen=True)
class Preprocessing:
    """What a frame goes through before the network (training and runtime alike).

    size: network input (width, height), pixels. crop: centre crop (width, height) applied
    to the frame before resizing, or None. specular_inpaint: specular pixels (luma >
    ``specular_threshold``, ``specular_dilation_px`` dilation) are inpainted first.
    """

    size: tuple[int, int]
    crop: tuple[int, int] | None = None
    specular_inpaint: bool = True
    specular_threshold: float = SPECULAR_THRESHOLD
    specular_dilation_px: int = SPECULAR_DILATION_PX
    input_range: str = "RGB float32 in [0, 1], NCHW"
    normalization_in_graph: bool = True
    mean: tuple[float, float, float] = IMAGENET_MEAN
    std: tuple[float, float, float] = IMAGENET_STD

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Preprocessing:
        d = dict(d)
        d["size"] = tuple(int(v) for v in d["size"])
        if d.get("crop") is not None:
            d["crop"] = tuple(int(v) for v in d["crop"])
        for k in ("mean", "std"):
            if k in d:
                d[k] = tuple(float(v) for v in d[k])
        known = {f.name for f in fields(cls)}
        return cls(**{k: v for k, v in d.items() if k in known})


@dataclass(frozen=True)
class ModelMetadata:
    """Everything the runtime needs to know about an exported net.

    kind: ``depth``, ``pose`` or ``descriptors``. inputs / outputs: one dict per graph
    input/output with ``name``, ``shape`` (ints or axis names), ``dtype`` and ``meaning``
    (outputs also ``units``). depth: ``{"min_depth", "max_depth" (metres), "conversion"}``
    for depth models. descriptor_sampling: ``dense`` or ``keypoints`` for descriptors models
    (None: dense). training_config: the model and data settings it was trained with.
    checkpoint: ``{"file", "sha256"}``. parity: ``{"max_abs_diff", "tolerance", "frames"}``
    of the check run at export time. precision: ``float32``, ``float16`` or ``int8`` (the
    graph's arithmetic; inputs and outputs are float32 in all three).
    """

    kind: str
    inputs: list[dict[str, Any]]
    outputs: list[dict[str, Any]]
    preprocessing: Preprocessing
    dynamic_batch: bool = True
    dynamic_size: bool = False
    descriptor_dim: int | None = None
    descriptor_sampling: str | None = None
    precision: str = "float32"
    depth: dict[str, Any] | None = None
    opset: int | None = None
    training_config: dict[str, Any] = field(default_factory=dict)
    checkpoint: dict[str, Any] = field(default_factory=dict)
    parity: dict[str, Any] = field(default_factory=dict)
    project_version: str = "unknown"
    created: str = ""
    schema_version: int = SCHEMA_VERSION

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise InputError(f"model kind must be one of {KINDS}, got {self.kind!r}")
        if self.precision not in PRECISIONS:
            raise InputError(f"precision must be one of {PRECISIONS}, got {self.precision!r}")
        if self.descriptor_sampling is not None and (self.kind != "descriptors"
                                                     or self.descriptor_sampling not in SAMPLINGS):
            raise InputError(f"descriptor_sampling must be one of {SAMPLINGS} on a descriptors model, got "
                             f"{self.descriptor_sampling!r} on a {self.kind} model")

    # -- serialisation -------------------------------------------------------------------
    def to_props(self) -> dict[str, str]:
        """``{"c3f.<field>": JSON}`` for ONNX ``metadata_props``."""
        d = asdict(self)
        return {KEY_PREFIX + k: json.dumps(v, sort_keys=True) for k, v in d.items()}

    @classmethod
    def from_props(cls, props: dict[str, str], source: str = "model") -> ModelMetadata:
        """Parse ``metadata_props``; InputError naming ``source`` when they are not ours,
        incomplete, or from a newer schema."""
        key = KEY_PREFIX + "schema_version"
        if key not in props:
            raise InputError(f"{source}: not a C3Fusion export (no {key} in the ONNX metadata)")
        try:
            values = {k[len(KEY_PREFIX):]: json.loads(v) for k, v in props.items() if k.startswith(KEY_PREFIX)}
        except json.JSONDecodeError as exc:
            raise InputError(f"{source}: unreadable C3Fusion metadata ({exc.msg})") from None
        version = values["schema_version"]
        if not isinstance(version, int) or isinstance(version, bool) or version < 1:
            raise InputError(f"{source}: invalid metadata schema version {version!r}")
        if version > SCHEMA_VERSION:
            raise InputError(
                f"{source}: metadata schema version {version} is newer than this c3f_slam reads "
                f"({SCHEMA_VERSION}); upgrade c3f_slam or re-export with this version"
            )
        missing = [k for k in REQUIRED if k not in values]
        if missing:
            raise InputError(f"{source}: C3Fusion metadata lacks {', '.join(KEY_PREFIX + k for k in missing)}")
        known = {f.name for f in fields(cls)}
        kwargs = {k: v for k, v in values.items() if k in known}
        try:
            kwargs["preprocessing"] = Preprocessing.from_dict(values["preprocessing"])
        except (KeyError, TypeError, ValueError) as exc:
            raise InputError(f"{source}: bad c3f.preprocessing metadata ({exc})") from None
        if len(kwargs["preprocessing"].size) != 2 or min(kwargs["preprocessing"].size) < 1:
            raise InputError(f"{source}: bad c3f.preprocessing metadata (size must be (width, height) > 0)")
        try:
            return cls(**kwargs)
        except InputError as exc:  # e.g. an unknown kind: name the file
            raise InputError(f"{source}: {exc}") from None
        except TypeError as exc:
            raise InputError(f"{source}: bad C3Fusion metadata ({exc})") from None

    # -- convenience ---------------------------------------------------------------------
    @property
    def sampling(self) -> str | None:
        """``dense`` or ``keypoints`` for a descriptors model (no field: ``dense``); None otherwise."""
        if self.kind != "descriptors":
            return None
        return self.descriptor_sampling or "dense"

    @property
    def input_size(self) -> tuple[int, int]:
        """Network input (width, height), pixels."""
        return self.preprocessing.size

    def describe(self) -> str:
        """One line for logs: kind, size, outputs."""
        w, h = self.input_size
        outs = ", ".join(f"{o['name']} [{o.get('units', '')}]" for o in self.outputs)
        kind = "descriptors (at keypoints)" if self.sampling == "keypoints" else self.kind
        if self.precision != "float32":
            kind = f"{self.precision} {kind}"
        return f"{kind} model, input {w}x{h}{' (any size)' if self.dynamic_size else ''}, outputs {outs}"


__all__ = ["SCHEMA_VERSION", "KINDS", "SAMPLINGS", "PRECISIONS", "KEY_PREFIX", "Preprocessing", "ModelMetadata"]
