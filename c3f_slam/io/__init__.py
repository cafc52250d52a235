"""File formats: the project's sequence layout and TUM trajectories (atomic writes: :mod:`c3f_core.atomic`)."""

from c3f_slam.io.sequence import Sequence, SequenceWriter, read_depth_png, read_rgb
from c3f_slam.io.tum import read_tum, write_tum

__all__ = [
    "Sequence",
    "SequenceWriter",
    "read_depth_png",
    "read_rgb",
    "read_tum",
    "write_tum",
]
