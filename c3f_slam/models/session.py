"""Open a C3Fusion ONNX export with onnxruntime and check it against its metadata.

:class:`OnnxModel` is the one loader: it reads the :class:`ModelMetadata` stored in the file,
checks that the graph's inputs and outputs are the ones the metadata (and the model kind)
promise, and validates every feed before running. Every problem is an
:class:`~c3f_core.errors.InputError` with a one-line message that starts with the
command-line option and the file, e.g. ``--depth-model: x.onnx is a descriptors model,
expected a depth model``.

Graph contract per kind (names fixed by the exporter; images NCHW float32 RGB in [0, 1]):

- depth: ``image`` (B, 3, H, W) -> ``depth`` (B, 1, H, W), metres;
- descriptors: ``image`` -> ``descriptors`` (B, C, H, W), unit norm per pixel, C = descriptor_dim;
  a keypoint descriptors file (metadata ``descriptor_sampling: keypoints``): ``image`` and
  ``keypoints`` (B, N, 2) float32 (u, v) network-grid pixels -> ``descriptors`` (B, N, C), unit norm;
- pose: ``image_a``, ``image_b`` (earlier frame first) -> ``T_ba`` (B, 4, 4), frame-a camera
  coordinates into frame b, metres.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from c3f_core.errors import InputError
from c3f_slam.models.metadata import ModelMetadata
from c3f_slam.models.zoo import entry as zoo_entry
from c3f_slam.models.zoo import is_zoo_name

#: (input names, output name) of the graph, per model kind.
GRAPH_IO: dict[str, tuple[tuple[str, ...], str]] = {
    "depth": (("image",), "depth"),
    "descriptors": (("image",), "descriptors"),
    "pose": (("image_a", "image_b"), "T_ba"),
}
#: (input names, output name) of a keypoint descriptors graph (``descriptor_sampling: keypoints``)
KEYPOINT_GRAPH_IO: tuple[tuple[str, ...], str] = (("image", "keypoints"), "descriptors")
#: the input of a keypoint descriptors graph that holds the (B, N, 2) keypoints
KEYPOINTS = "keypoints"


#: onnxruntime's CPU execution provider: the default, and what every session falls back to
CPU = "CPUExecutionProvider"
DEFAULT_PROVIDERS: tuple[str, ...] = (CPU,)
#: providers whose sessions run with IO binding (inputs copied to the device once, outputs back once)
DEVICE_PROVIDERS = ("CUDAExecutionProvider", "TensorrtExecutionProvider")


def check_providers(providers: str | Sequence[str], option: str = "--providers") -> tuple[str, ...]:
    """The onnxruntime execution providers of ``providers`` (names, or one comma-separated
    string), in order of preference; InputError naming ``option`` for an empty list, a name
    given twice, a name onnxruntime does not know, or one this onnxruntime build lacks."""
    import onnxruntime as ort

    names = [n.strip() for n in providers.split(",")] if isinstance(providers, str) else [str(n) for n in providers]
    if not names or not all(names):
        raise InputError(f"{option}: give comma-separated onnxruntime provider names, e.g. "
                         f"CUDAExecutionProvider,{CPU}")
    twice = [n for k, n in enumerate(names) if n in names[:k]]
    if twice:
        raise InputError(f"{option}: {twice[0]} is given twice")
    for name in names:
        if name not in ort.get_all_providers():
            raise InputError(f"{option}: {name!r} is not an onnxruntime execution provider (this build has: "
                             f"{', '.join(ort.get_available_providers())}; all names: onnxruntime.get_all_providers())")
        if name not in ort.get_available_providers():
            raise InputError(f"{option}: {name} is not available in this onnxruntime build (available: "
                             f"{', '.join(ort.get_available_providers())}); CUDA needs the onnxruntime-gpu package")
    return tuple(names)


def graph_io(meta: ModelMetadata) -> tuple[tuple[str, ...], str]:
    """(input names, output name) the graph of a file with metadata ``meta`` must have."""
    return KEYPOINT_GRAPH_IO if meta.sampling == "keypoints" else GRAPH_IO[meta.kind]


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip()
    line = text.splitlines()[0] if text else type(exc).__name__
    return line if len(line) <= 200 else line[:197] + "..."


class OnnxModel:
    """An exported C3Fusion net on onnxruntime (CPU by default).

    Args:
        path: the .onnx file, or ``zoo:NAME`` for the zoo entry's file of ``expect_kind`` (its
            SHA-256 checked against the card; :mod:`c3f_slam.models.zoo`).
        expect_kind: ``depth``, ``descriptors`` or ``pose``; another kind is an InputError.
        threads: onnxruntime intra-op threads.
        option: the command-line option that named the file (prefix of every error message;
            None: the file alone).
        providers: onnxruntime execution providers in order of preference
            (:func:`check_providers`; default CPU only). With CUDA (or TensorRT) the session runs
            with IO binding; on CPU with ``session.run``.

    Attributes: ``metadata`` (:class:`ModelMetadata`), ``input_names``, ``output_names``,
    ``path``, ``where`` (``"<option>: <path>"``, the prefix of its error messages),
    ``providers`` (those the session uses, ``session.get_providers()``), ``io_binding``.
    """

    def __init__(
        self, path: str | Path, expect_kind: str | None = None, threads: int = 2, option: str | None = "--model",
        providers: Sequence[str] = DEFAULT_PROVIDERS,
    ) -> None:
        if is_zoo_name(path):
            found = zoo_entry(str(path), option or "model")
            path = found.file_for(expect_kind or found.kind, option or "model")
        self.path = Path(path)
        self.option = option
        self.where = f"{option}: {path}" if option else str(path)
        if not self.path.exists():
            raise InputError(f"{self.where}: model file not found")
        if not self.path.is_file():
            raise InputError(f"{self.where}: is a folder, expected an .onnx file")
        self.session = self._open(int(threads), check_providers(providers))
        self.providers = tuple(self.session.get_providers())
        self.io_binding = any(p in DEVICE_PROVIDERS for p in self.providers)
        try:
            props = dict(self.session.get_modelmeta().custom_metadata_map)
            self.metadata = ModelMetadata.from_props(props, source=str(path))
        except InputError as exc:
            raise InputError(f"{option}: {exc}" if option else str(exc)) from None
        self.input_names = tuple(i.name for i in self.session.get_inputs())
        self.output_names = tuple(o.name for o in self.session.get_outputs())
        if expect_kind is not None and self.metadata.kind != expect_kind:
            raise InputError(
                f"{self.where} is a {self.metadata.kind} model, expected a {expect_kind} model"
            )
        self._check_graph()

    # ------------------------------------------------------------------ loading
    def _open(self, threads: int, providers: tuple[str, ...]):
        import onnxruntime as ort

        opts = ort.SessionOptions()
        self.threads = max(1, threads)  #: onnxruntime intra-op threads
        opts.intra_op_num_threads = self.threads
        opts.inter_op_num_threads = 1
        opts.log_severity_level = 3  # errors only; ours are raised as InputError
        try:
            return ort.InferenceSession(str(self.path), sess_options=opts, providers=list(providers))
        except Exception as exc:  # onnxruntime raises its own types (InvalidProtobuf, Fail, ...)
            raise InputError(f"{self.where}: not a readable ONNX model ({_first_line(exc)})") from None

    def _fail(self, what: str) -> InputError:
        return InputError(f"{self.where}: {what}")

    def _check_graph(self) -> None:
        """The graph's inputs/outputs must be the kind's contract and the metadata's."""
        meta = self.metadata
        want_in, want_out = graph_io(meta)
        meta_in = tuple(i.get("name") for i in meta.inputs)
        meta_out = tuple(o.get("name") for o in meta.outputs)
        if meta_in != want_in or meta_out != (want_out,):
            what = "a keypoint descriptors" if meta.sampling == "keypoints" else f"a {meta.kind}"
            raise self._fail(
                f"metadata declares inputs {list(meta_in)} and outputs {list(meta_out)}; "
                f"{what} model has inputs {list(want_in)} and output {want_out!r}"
            )
        if self.input_names != want_in or want_out not in self.output_names:
            raise self._fail(
                f"graph has inputs {list(self.input_names)} and outputs {list(self.output_names)}, "
                f"but the metadata declares inputs {list(want_in)} and output {want_out!r}"
            )
        for node in self.session.get_inputs():
            self._check_input_node(node)
        self._check_output_node(next(o for o in self.session.get_outputs() if o.name == want_out))

    def _check_input_node(self, node) -> None:
        """An image input (B, 3, H, W) float, at the metadata size unless dynamic; a keypoints
        input (B, N, 2) float."""
        if node.type != "tensor(float)":
            raise self._fail(f"graph input {node.name!r} is {node.type}, expected tensor(float)")
        shape = list(node.shape)
        if node.name == KEYPOINTS and self.metadata.sampling == "keypoints":
            if len(shape) != 3 or (isinstance(shape[2], int) and shape[2] != 2):
                raise self._fail(f"graph input {node.name!r} has shape {shape}, expected (B, N, 2)")
            return
        if len(shape) != 4 or (isinstance(shape[1], int) and shape[1] != 3):
            raise self._fail(f"graph input {node.name!r} has shape {shape}, expected (B, 3, H, W)")
        w, h = self.metadata.input_size
        fixed = shape[2:]
        if not self.metadata.dynamic_size and all(isinstance(v, int) for v in fixed) and fixed != [h, w]:
            raise self._fail(f"graph input {node.name!r} is {fixed[1]}x{fixed[0]} but the metadata size is {w}x{h}")

    def _check_output_node(self, out) -> None:
        """(B, 4, 4) for pose, (B, 1, H, W) depth, (B, C, H, W) dense or (B, N, C) keypoint descriptors."""
        meta = self.metadata
        shape = list(out.shape)
        if meta.kind == "pose":
            ok = len(shape) == 3 and all(not isinstance(v, int) or v == 4 for v in shape[1:])
            expected = "(B, 4, 4)"
        else:
            channels = 1 if meta.kind == "depth" else meta.descriptor_dim
            if meta.kind == "descriptors" and not (isinstance(channels, int) and channels > 0):
                raise self._fail(f"descriptors model without a valid descriptor_dim ({channels!r}) in its metadata")
            if meta.sampling == "keypoints":
                ok = len(shape) == 3 and (not isinstance(shape[2], int) or shape[2] == channels)
                expected = f"(B, N, {channels})"
            else:
                ok = len(shape) == 4 and (not isinstance(shape[1], int) or shape[1] == channels)
                expected = f"(B, {channels}, H, W)"
        if not ok:
            raise self._fail(f"graph output {out.name!r} has shape {shape}, expected {expected}")

    # ------------------------------------------------------------------ running
    @property
    def kind(self) -> str:
        return self.metadata.kind

    def check_image_batch(self, name: str, x: object) -> np.ndarray:
        """Validate one image feed: ndarray (B, 3, H, W) float32, H, W = the metadata size
        unless the model is dynamic in size. Returns it contiguous."""
        if not isinstance(x, np.ndarray):
            raise self._fail(f"input {name!r} must be a NumPy array, got {type(x).__name__}")
        if x.dtype != np.float32:
            raise self._fail(f"input {name!r} must be float32 RGB in [0, 1], got {x.dtype}")
        if x.ndim != 4 or x.shape[1] != 3:
            raise self._fail(f"input {name!r} must be NCHW (B, 3, H, W), got shape {tuple(x.shape)}")
        if x.shape[0] < 1:
            raise self._fail(f"input {name!r} is an empty batch")
        w, h = self.metadata.input_size
        if not self.metadata.dynamic_size and (x.shape[3], x.shape[2]) != (w, h):
            raise self._fail(f"input image is {x.shape[3]}x{x.shape[2]} but the model takes {w}x{h}")
        return np.ascontiguousarray(x)

    def check_keypoints(self, name: str, x: object, batch: int) -> np.ndarray:
        """Validate a keypoints feed: ndarray (B, N, 2) float32, finite, N >= 1, B = ``batch``
        (the images'). Returns it contiguous."""
        if not isinstance(x, np.ndarray):
            raise self._fail(f"input {name!r} must be a NumPy array, got {type(x).__name__}")
        if x.dtype != np.float32:
            raise self._fail(f"input {name!r} must be float32 (u, v) network pixels, got {x.dtype}")
        if x.ndim != 3 or x.shape[2] != 2:
            raise self._fail(f"input {name!r} must be (B, N, 2) (u, v) network pixels, got shape {tuple(x.shape)}")
        if x.shape[0] != batch:
            raise self._fail(f"input {name!r} has a batch of {x.shape[0]}, the images {batch}")
        if x.shape[1] < 1:
            raise self._fail(f"input {name!r} holds no keypoints (N = 0)")
        if not np.isfinite(x).all():
            raise self._fail(f"input {name!r} holds non-finite coordinates")
        return np.ascontiguousarray(x)

    def run(self, feeds: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
        """Run the graph on validated ``feeds`` (name -> (B, 3, H, W) float32 images, and for a
        keypoint descriptors file ``keypoints`` (B, N, 2) float32); returns {output name: array}.
        Image inputs of one call share batch and size."""
        names = set(feeds)
        if names != set(self.input_names):
            raise self._fail(f"feeds {sorted(names)} do not match the model inputs {list(self.input_names)}")
        images = [n for n in self.input_names if not (n == KEYPOINTS and self.metadata.sampling == "keypoints")]
        checked = {n: self.check_image_batch(n, feeds[n]) for n in images}
        shapes = {tuple(v.shape) for v in checked.values()}
        if len(shapes) > 1:
            raise self._fail(f"inputs {list(self.input_names)} differ in shape: {sorted(shapes)}")
        if len(images) < len(self.input_names):
            checked[KEYPOINTS] = self.check_keypoints(KEYPOINTS, feeds[KEYPOINTS], next(iter(shapes))[0])
        try:
            values = self._run_bound(checked) if self.io_binding else self.session.run(list(self.output_names), checked)
        except Exception as exc:  # an ONNX Runtime failure on a validated input is the file's fault
            raise self._fail(f"inference failed ({_first_line(exc)})") from None
        return dict(zip(self.output_names, values))

    def _run_bound(self, feeds: dict[str, np.ndarray]) -> list[np.ndarray]:
        """One run with IO binding: the inputs copied to the session's device once, the outputs
        kept there and copied back once (on a CPU-only session, bound on the CPU)."""
        device = "cuda" if any(p in DEVICE_PROVIDERS for p in self.providers) else "cpu"
        binding = self.session.io_binding()
        for name, value in feeds.items():
            binding.bind_cpu_input(name, value)
        for name in self.output_names:
            binding.bind_output(name, device)
        self.session.run_with_iobinding(binding)
        return binding.copy_outputs_to_cpu()

    def __repr__(self) -> str:
        return f"OnnxModel({str(self.path)!r}: {self.metadata.describe()})"
