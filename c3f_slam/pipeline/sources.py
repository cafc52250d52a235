"""Where a run's frames, depth and descriptors come from: the command-line choices
(:class:`RunInputs`), checked once, opened into a :class:`RunSources`.

``descriptors`` / ``depth_source`` None follow the models given: ``--depth-model`` alone
means model depth, ``--feature-model`` alone ContraFeat, else depth files and SIFT.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, replace
from pathlib import Path

from c3f_core.errors import InputError
from c3f_slam.camera.intrinsics import FovGuess, PinholeCamera
from c3f_slam.config import FrameQualityConfig, TissueConfig
from c3f_slam.frames.quality import FrameQualityGate
from c3f_slam.frames.stream import FrameStream
from c3f_slam.frames.tissue import TissueMask, resolve_tissue_mask, whole_frame
from c3f_slam.models import DepthModel, DescriptorModel
from c3f_slam.models.session import DEFAULT_PROVIDERS
from c3f_slam.pipeline.frontend import (
    ContraFeatDescriptors,
    DepthProvider,
    DescriptorProvider,
    FileDepth,
    ModelDepth,
    SiftDescriptors,
)

DESCRIPTORS = ("sift", "contrafeat")
DEPTH_SOURCES = ("files", "model")


@dataclass(frozen=True, kw_only=True)
class RunInputs:
    """The command-line choices of a run's inputs (given by name)."""

    descriptors: str | None = None  #: sift | contrafeat; None: contrafeat when feature_model is given
    depth_source: str | None = None  #: files | model; None: model when depth_model is given
    depth_model: str | Path | None = None  #: DepthNet ONNX export
    feature_model: str | Path | None = None  #: ContraFeat ONNX export
    #: intrinsics of a video (default camera.json beside it); a FovGuess: ``--fov``, no calibration
    camera: str | Path | PinholeCamera | FovGuess | None = None
    #: onnxruntime intra-op threads per model; None: :func:`default_threads` (one core left for the back-end)
    threads: int | None = None
    depth_scale: float | None = None  #: factor on model depth; None: the model's metric_scale, else 1
    max_bad_frames: int = 10  #: unreadable frames skipped and counted; one more fails the run
    providers: tuple[str, ...] = DEFAULT_PROVIDERS  #: onnxruntime execution providers of every model, preferred first

    def resolved(self) -> RunInputs:
        """A copy with ``descriptors`` and ``depth_source`` decided (:func:`resolve_sources`)."""
        descriptors, depth_source = resolve_sources(self.descriptors, self.depth_source, self.depth_model,
                                                    self.feature_model)
        return replace(self, descriptors=descriptors, depth_source=depth_source)


def resolve_sources(
    descriptors: str | None, depth_source: str | None, depth_model: str | Path | None,
    feature_model: str | Path | None,
) -> tuple[str, str]:
    """(descriptors, depth source) of the command-line choices. InputError for unknown
    values, a model choice without its file, or a file left unused."""
    descriptors = descriptors or ("contrafeat" if feature_model else "sift")
    depth_source = depth_source or ("model" if depth_model else "files")
    if descriptors not in DESCRIPTORS:
        raise InputError(f"--descriptors must be one of {DESCRIPTORS}, got {descriptors!r}")
    if depth_source not in DEPTH_SOURCES:
        raise InputError(f"--depth-source must be one of {DEPTH_SOURCES}, got {depth_source!r}")
    if descriptors == "contrafeat" and not feature_model:
        raise InputError("--descriptors contrafeat needs --feature-model FILE.onnx (a ContraFeat export)")
    if descriptors != "contrafeat" and feature_model:
        raise InputError(f"--feature-model is used with --descriptors contrafeat, not {descriptors}")
    if depth_source == "model" and not depth_model:
        raise InputError("--depth-source model needs --depth-model FILE.onnx (a DepthNet export)")
    if depth_source != "model" and depth_model:
        raise InputError(f"--depth-model is used with --depth-source model, not {depth_source}")
    return descriptors, depth_source


def default_threads() -> int:
    """onnxruntime threads per model when none are given: the machine's cores less one, which the
    back-end uses while perception runs ahead of it (at least 1). On 2 cores: 1, which made whole
    model-mode runs 1.3x faster than 2 threads at 128 px and equal at 224 px
    (docs/lab_notes/2026-12-05-slam-speed.md)."""
    return max(1, (os.cpu_count() or 2) - 1)


def make_providers(inputs: RunInputs, camera: PinholeCamera | None = None,
                   tissue: TissueMask | None = None) -> tuple[DescriptorProvider, DepthProvider]:
    """The descriptor and depth providers of ``inputs``; model providers load their ONNX file
    and are bound to ``camera``, the frames' intrinsics; every provider to ``tissue``, the
    frames' tissue area (None: the whole frame). InputError otherwise."""
    inputs = inputs.resolved()
    descriptors, depth_source = inputs.descriptors, inputs.depth_source
    if camera is None and (descriptors == "contrafeat" or depth_source == "model"):
        raise ValueError("model providers need the frames' camera")
    pixels = None if tissue is None or tissue.whole_frame else tissue.pixels
    desc: DescriptorProvider = SiftDescriptors()
    depth: DepthProvider = FileDepth(pixels)
    threads = inputs.threads or default_threads()
    if descriptors == "contrafeat":  # the export's keypoint file when it sits beside the dense one
        desc = ContraFeatDescriptors(DescriptorModel(inputs.feature_model, threads, "--feature-model",
                                                     prefer_keypoints=True, providers=inputs.providers), camera,
                                     pixels)
    if depth_source == "model":
        depth = ModelDepth(DepthModel(inputs.depth_model, threads, "--depth-model",
                                      providers=inputs.providers), camera, inputs.depth_scale, pixels)
    return desc, depth


@dataclass(kw_only=True)
class RunSources:
    """The opened inputs of a run: the frame stream and the two providers."""

    descriptors: str  #: resolved choice
    depth_source: str  #: resolved choice
    stream: FrameStream
    describer: DescriptorProvider
    depth: DepthProvider
    tissue: TissueMask  #: the frames' tissue area (:mod:`c3f_slam.frames.tissue`)
    max_bad_frames: int  #: RunInputs.max_bad_frames

    @property
    def camera(self) -> PinholeCamera:
        return self.stream.camera

    def summary(self) -> dict:
        """What summary.json records about the inputs: the choices, the camera (the frames' pinhole
        intrinsics) and where it came from (``camera_source``: ``file PATH`` or ``fov guess DEG deg``,
        plus the lens when the frames were undistorted), the depth scale
        and per model the file run, its precision and the onnxruntime providers its session uses (``models``;
        for descriptors also the file given, how it samples and whether the export's keypoint
        file is used, or why not)."""
        out: dict = {"descriptors": self.descriptors, "depth_source": self.depth_source,
                     "camera": self.camera.to_dict(), "camera_source": self.stream.camera_source,
                     "tissue_mask": self.tissue.summary()}
        if isinstance(self.depth, ModelDepth):
            out["depth_scale"] = {"factor": self.depth.scale, "source": self.depth.scale_source}
        out["models"] = {
            name: {"file": str(p.model.onnx.path), "model": p.model.metadata.describe(),
                   "precision": p.model.metadata.precision, "providers": list(p.model.onnx.providers),
                   "threads": p.model.onnx.threads}
            for name, p in (("descriptors", self.describer), ("depth", self.depth)) if hasattr(p, "model")
        }
        if isinstance(self.describer, ContraFeatDescriptors):
            model = self.describer.model
            out["models"]["descriptors"].update(given=str(model.given), descriptor_sampling=model.sampling,
                                                keypoint_file=model.keypoint_file)
        return out


def open_sources(sequence: str | Path, inputs: RunInputs, *, stride: int = 1, max_frames: int | None = None,
                 tissue: TissueConfig | None = None, quality: FrameQualityConfig | None = None) -> RunSources:
    """Check resolved ``inputs`` (:meth:`RunInputs.resolved`) against ``sequence`` (a sequence
    folder, or a video with model depth), find the frames' tissue area (``tissue``; None: the
    whole frame), give the stream its frame-quality gate inside it (``quality``; None or not
    enabled: none) and open the stream and providers. InputError on any mismatch."""
    descriptors, depth_source = inputs.descriptors, inputs.depth_source
    if descriptors is None or depth_source is None:
        raise ValueError("open_sources needs resolved inputs (RunInputs.resolved())")
    stream = FrameStream(sequence, camera=inputs.camera, use_depth=depth_source == "files", step=stride,
                         max_frames=max_frames)
    if inputs.camera is not None and stream.sequence is not None:
        raise InputError(f"{sequence}: --camera is for videos; a sequence folder uses its camera.json")
    if depth_source == "files":
        if stream.sequence is None:
            raise InputError(f"{sequence}: --depth-source files needs a sequence folder, not a video")
        if not stream.sequence.has_depth:
            raise InputError(f"{sequence}: --depth-source files but the sequence has no depth/ folder")
    if inputs.max_bad_frames < 0:
        raise InputError(f"--max-bad-frames must be >= 0, got {inputs.max_bad_frames}")
    if inputs.depth_scale is not None and depth_source != "model":
        raise InputError("--depth-scale applies to model depth (--depth-model) only")
    mask = (resolve_tissue_mask(stream, tissue, _camera_file(stream, inputs.camera)) if tissue is not None
            else whole_frame(stream.camera.width, stream.camera.height))
    if quality is not None and quality.enabled:
        stream.quality = FrameQualityGate(quality, None if mask.whole_frame else mask.pixels)
    describer, depth = make_providers(inputs, stream.camera, mask)
    return RunSources(descriptors=descriptors, depth_source=depth_source, stream=stream, describer=describer,
                      depth=depth, tissue=mask, max_bad_frames=inputs.max_bad_frames)


def _camera_file(stream: FrameStream, camera: str | Path | PinholeCamera | FovGuess | None) -> Path | None:
    """The camera.json the frames' intrinsics came from (None when given as an object or guessed, --fov)."""
    return stream.camera_file
