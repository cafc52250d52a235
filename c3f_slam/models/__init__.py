"""Exported C3Fusion networks on onnxruntime, torch-free (docs/design.md, SLAM runtime).

- :mod:`.metadata`: the schema of the metadata every export carries (:class:`ModelMetadata`);
- :mod:`.session`: :class:`OnnxModel`, the loader that checks file, metadata and graph and
  validates feeds (one-line :class:`~c3f_core.errors.InputError` otherwise);
- :mod:`.grid`: :class:`NetworkView`, frame pixels <-> network pixels (crop + resize);
- :mod:`.nets`: :class:`DepthModel`, :class:`DescriptorModel`, :class:`PoseModel` on uint8
  RGB frames with their camera (descriptors from a dense-map file or a keypoint file);
- :mod:`.variants`: the keypoint descriptors file of the same export beside a dense one;
- :mod:`.summary`: :func:`format_metadata`, the ``inspect`` report.

Example::

    depth = DepthModel("depth.onnx").predict(rgb, camera)          # (H, W) metres, frame grid
    desc = DescriptorModel("feat.onnx").describe(rgb, camera, xy)  # (N, C) unit norm
"""

from c3f_slam.models.grid import NetworkView
from c3f_slam.models.metadata import KINDS, SCHEMA_VERSION, ModelMetadata, Preprocessing
from c3f_slam.models.nets import DepthModel, DescriptorModel, FrameModel, PoseModel
from c3f_slam.models.session import GRAPH_IO, OnnxModel
from c3f_slam.models.summary import format_metadata

__all__ = [
    "GRAPH_IO",
    "KINDS",
    "SCHEMA_VERSION",
    "DepthModel",
    "DescriptorModel",
    "FrameModel",
    "ModelMetadata",
    "NetworkView",
    "OnnxModel",
    "PoseModel",
    "Preprocessing",
    "format_metadata",
]
