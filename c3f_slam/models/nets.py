"""DepthNet, ContraFeat and PoseNet ONNX exports on video frames (no torch).

Each class opens its file with :class:`OnnxModel` (checking the kind) and runs the training
pre-processing of the metadata (:func:`c3f_slam.frames.preprocess.prepare_network_input`: centre
crop, resize, specular inpainting) on (H, W, 3) uint8 RGB frames with their
:class:`~c3f_slam.camera.intrinsics.PinholeCamera`. Two levels of API:

- ``*_batch`` methods take network inputs, (B, 3, h, w) float32 RGB in [0, 1] (see
  :meth:`FrameModel.prepare`), and return the network-grid outputs;
- the frame methods map the results back to the frame: depth in the frame's pixel grid,
  descriptors at keypoints given in frame pixels, poses as 4x4 float64.

Conventions: metres; pixel centres at integer coordinates; camera x right, y down, z forward.
"""

from __future__ import annotations

import weakref
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from c3f_core.errors import InputError
from c3f_slam.camera.intrinsics import PinholeCamera
from c3f_slam.frames.preprocess import prepare_network_input
from c3f_slam.matching.descriptors import sample_descriptor_map
from c3f_slam.models.grid import UPSAMPLING, NetworkView
from c3f_slam.models.metadata import ModelMetadata
from c3f_slam.models.session import DEFAULT_PROVIDERS, OnnxModel
from c3f_slam.models.variants import keypoint_file_beside
from c3f_slam.models.zoo import is_zoo_name

#: The command-line option that names each kind's file (prefix of error messages).
OPTIONS = {"depth": "--depth-model", "descriptors": "--feature-model", "pose": "--pose-model"}


class FrameModel:
    """Common part: the ONNX session, the metadata and the frame -> network-input step.

    ``option``: the option named in error messages (default :data:`OPTIONS` of the kind);
    ``providers``: onnxruntime execution providers (:class:`OnnxModel`; default CPU only).

    The last prepared input is shared by all models (one entry, class level): when a depth
    and a descriptor model with the same pre-processing see the same frame array, the crop,
    resize and inpainting run once. The entry is keyed by the frame object itself (a weak
    reference), the camera, the pre-processing and the tissue mask (the same array), so a new
    frame array is always prepared;
    frames must not be modified in place between the two calls.
    """

    kind = ""
    _last_input: tuple | None = None  # (weakref to the frame, camera, preprocessing, tissue mask, input)

    def __init__(self, path: str | Path, threads: int = 2, option: str | None = None,
                 providers: Sequence[str] = DEFAULT_PROVIDERS) -> None:
        self.onnx = OnnxModel(path, expect_kind=self.kind, threads=threads, option=option or OPTIONS[self.kind],
                              providers=providers)

    @property
    def metadata(self) -> ModelMetadata:
        return self.onnx.metadata

    def view(self, camera: PinholeCamera) -> NetworkView:
        """Crop box and network-grid intrinsics for frames of ``camera`` (InputError naming the
        model when its crop does not fit the frames)."""
        pp = self.metadata.preprocessing
        try:
            return NetworkView.of(camera, pp.crop, pp.size)
        except InputError as exc:
            raise InputError(f"{self.onnx.where}: {exc} (frames from camera intrinsics)") from None

    def prepare(self, rgb: np.ndarray, camera: PinholeCamera,
                tissue: np.ndarray | None = None) -> tuple[np.ndarray, NetworkView]:
        """(3, h, w) float32 RGB in [0, 1] network input of an (H, W, 3) uint8 frame, and its view;
        ``tissue``: (H, W) bool tissue area (the border is filled from it; None: the whole frame)."""
        rgb = np.asarray(rgb)
        if rgb.dtype != np.uint8 or rgb.ndim != 3 or rgb.shape[2] != 3:
            raise InputError(f"frame must be (H, W, 3) uint8 RGB, got {rgb.dtype} {rgb.shape}")
        view = self.view(camera)
        pp = self.metadata.preprocessing
        last = FrameModel._last_input
        if last is not None and last[0]() is rgb and last[1] == camera and last[2] == pp and last[3] is tissue:
            return last[4], view
        net_rgb, _, _ = prepare_network_input(
            rgb, camera, crop=pp.crop, size=pp.size, specular=pp.specular_inpaint,
            specular_threshold=pp.specular_threshold, specular_dilation_px=pp.specular_dilation_px, tissue=tissue,
        )
        x = np.ascontiguousarray(net_rgb.transpose(2, 0, 1), dtype=np.float32) / np.float32(255.0)
        x.flags.writeable = False
        FrameModel._last_input = (weakref.ref(rgb), camera, pp, tissue, x)
        return x, view

    def __repr__(self) -> str:
        return f"{type(self).__name__}({str(self.onnx.path)!r}: {self.metadata.describe()})"


class DepthModel(FrameModel):
    """DepthNet export: depth in metres (z along the optical axis).

    ``upsample``: how network-grid depth is resized back onto the frame's crop box,
    ``linear`` (default; smooth walls) or ``nearest`` (never mixes depths across an edge).
    """

    kind = "depth"

    def __init__(
        self, path: str | Path, threads: int = 2, option: str | None = None, upsample: str = "linear",
        providers: Sequence[str] = DEFAULT_PROVIDERS,
    ) -> None:
        if upsample not in UPSAMPLING:
            raise InputError(f"depth upsampling must be one of {tuple(UPSAMPLING)}, got {upsample!r}")
        super().__init__(path, threads, option, providers)
        self.upsample = upsample

    @property
    def depth_range(self) -> tuple[float, float] | None:
        """(min_depth, max_depth) in metres from the metadata, when recorded."""
        d = self.metadata.depth or {}
        return (float(d["min_depth"]), float(d["max_depth"])) if "min_depth" in d and "max_depth" in d else None

    @property
    def metric_scale(self) -> float | None:
        """Factor from the network's depth to metres measured on the training data at export
        (``depth.metric_scale``; self-supervised depth is known only up to a scale), when
        recorded and positive."""
        v = (self.metadata.depth or {}).get("metric_scale")
        try:
            v = float(v)
        except (TypeError, ValueError):
            return None
        return v if np.isfinite(v) and v > 0 else None

    def predict_batch(self, images: np.ndarray) -> np.ndarray:
        """(B, 3, h, w) float32 network inputs -> (B, h, w) float32 depth, metres (non-finite -> 0)."""
        depth = self.onnx.run({"image": images})["depth"][:, 0]
        return np.where(np.isfinite(depth), depth, 0.0).astype(np.float32)

    def predict_network(self, rgb: np.ndarray, camera: PinholeCamera,
                        tissue: np.ndarray | None = None) -> tuple[np.ndarray, NetworkView]:
        """Depth (h, w) float32 metres on the network grid of one frame, and the grid's view
        (``view.camera`` are its intrinsics); ``tissue`` as :meth:`FrameModel.prepare`."""
        x, view = self.prepare(rgb, camera, tissue)
        return self.predict_batch(x[None])[0], view

    def predict(self, rgb: np.ndarray, camera: PinholeCamera) -> np.ndarray:
        """(H, W) float32 depth in metres in the frame's pixel grid; 0 outside the crop box."""
        depth, view = self.predict_network(rgb, camera)
        return view.network_to_frame(depth, self.upsample)


class DescriptorModel(FrameModel):
    """ContraFeat export: unit-norm descriptors at keypoints, from a dense-map file (sampled
    here) or a keypoint file (``descriptor_sampling: keypoints``: sampled inside the graph, by
    the same rule).

    ``prefer_keypoints``: when ``path`` is a dense file (not a zoo name) and the keypoint file
    of the same export sits beside it (:func:`c3f_slam.models.variants.keypoint_file_beside`),
    that file is run instead. ``given`` is the file named; ``keypoint_file`` says which was used
    and why: ``given`` (the file named is a keypoint file), ``used``, or why not.
    """

    kind = "descriptors"

    def __init__(self, path: str | Path, threads: int = 2, option: str | None = None,
                 prefer_keypoints: bool = False, providers: Sequence[str] = DEFAULT_PROVIDERS) -> None:
        super().__init__(path, threads, option, providers)
        self.given = self.onnx.path
        self.keypoint_file = "given" if self.sampling == "keypoints" else "not looked for"
        if prefer_keypoints and self.sampling == "dense" and is_zoo_name(path):
            self.keypoint_file = "not looked for: a zoo entry's files are the ones its card lists"
        elif prefer_keypoints and self.sampling == "dense":
            found, self.keypoint_file = keypoint_file_beside(self.onnx.path, self.metadata, threads, self.onnx.option,
                                                             providers)
            if found is not None:
                self.onnx = found

    @property
    def descriptor_dim(self) -> int:
        return int(self.metadata.descriptor_dim)

    @property
    def sampling(self) -> str:
        """``dense`` (the file returns the map) or ``keypoints`` (descriptors at given keypoints)."""
        return self.metadata.sampling or "dense"

    def _dense_only(self) -> None:
        """InputError (one line, naming the option and file) for a keypoint file."""
        if self.sampling == "keypoints":
            raise InputError(f"{self.onnx.where}: is a keypoint descriptors model (descriptors at given keypoints "
                             "only); a dense descriptor map needs the dense file of its export (contrafeat.onnx)")

    def describe_batch(self, images: np.ndarray) -> np.ndarray:
        """(B, 3, h, w) float32 network inputs -> (B, C, h, w) float32 unit-norm descriptor maps
        (a dense file only)."""
        self._dense_only()
        return self.onnx.run({"image": images})["descriptors"]

    def describe_keypoints_batch(self, images: np.ndarray, keypoints: np.ndarray) -> np.ndarray:
        """(B, 3, h, w) float32 network inputs and (B, N, 2) float32 keypoints (u, v) in network
        pixels -> (B, N, C) float32 unit descriptors: the keypoint graph, or the dense map sampled
        by :func:`~c3f_slam.matching.sample_descriptor_map` (the same rule)."""
        if self.sampling == "keypoints":
            return self.onnx.run({"image": images, "keypoints": keypoints})["descriptors"]
        maps = self.describe_batch(images)
        kp = np.asarray(keypoints)
        if kp.ndim != 3 or kp.shape[0] != len(maps) or kp.shape[2] != 2:
            raise InputError(f"{self.onnx.where}: keypoints must be (B, N, 2) with B = {len(maps)}, got {kp.shape}")
        return np.stack([sample_descriptor_map(m, p, normalise=True) for m, p in zip(maps, kp)])

    def descriptor_map(self, rgb: np.ndarray, camera: PinholeCamera) -> tuple[np.ndarray, NetworkView]:
        """(C, h, w) descriptor map of one frame on the network grid, and the grid's view (a
        dense file only)."""
        self._dense_only()
        x, view = self.prepare(rgb, camera)
        return self.describe_batch(x[None])[0], view

    def describe(self, rgb: np.ndarray, camera: PinholeCamera, xy: np.ndarray,
                 tissue: np.ndarray | None = None) -> np.ndarray:
        """(N, C) float32 unit descriptors at (N, 2) keypoints (u, v) in frame pixels (``tissue``
        as :meth:`FrameModel.prepare`).

        Keypoints are mapped into the network grid (:meth:`NetworkView.frame_to_network`) and
        the map is sampled bilinearly with pixel centres at integer coordinates, clamped at the
        border (the training sampler: ``grid_sample(align_corners=True,
        padding_mode="border")``), then re-normalised: here on the dense map, or inside the
        graph of a keypoint file (keypoints as float32). Keypoints outside the crop box get the
        descriptor of the nearest border position.
        """
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        if len(xy) == 0:
            camera.check_image(np.shape(rgb), "frame")
            return np.zeros((0, self.descriptor_dim), np.float32)
        x, view = self.prepare(rgb, camera, tissue)
        net_xy = view.frame_to_network(xy)
        if self.sampling == "keypoints":
            return self.describe_keypoints_batch(x[None], net_xy[None].astype(np.float32))[0]
        return sample_descriptor_map(self.describe_batch(x[None])[0], net_xy, normalise=True)


class PoseModel(FrameModel):
    """PoseNet export: the relative pose of two frames of the same camera."""

    kind = "pose"

    def predict_batch(self, images_a: np.ndarray, images_b: np.ndarray) -> np.ndarray:
        """(B, 3, h, w) float32 inputs (a = earlier frames) -> (B, 4, 4) float32 ``T_ba``:
        frame-a camera coordinates into frame b (p_b = T_ba p_a), metres."""
        return self.onnx.run({"image_a": images_a, "image_b": images_b})["T_ba"]

    def predict(self, rgb_a: np.ndarray, rgb_b: np.ndarray, camera: PinholeCamera) -> np.ndarray:
        """(4, 4) float64 ``T_ba`` (p_b = T_ba p_a, metres) of two uint8 RGB frames, a the earlier."""
        xa, _ = self.prepare(rgb_a, camera)
        xb, _ = self.prepare(rgb_b, camera)
        return self.predict_batch(xa[None], xb[None])[0].astype(np.float64)
