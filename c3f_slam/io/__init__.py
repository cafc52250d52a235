"""File formats: the project's sequence layout, TUM trajectories, atomic writes."""

from c3f_slam.io.atomic import atomic_write, atomic_write_text
from c3f_slam.io.sequence import Sequence, SequenceWriter, read_depth_png, read_rgb
from c3f_slam.io.tum import read_tum, write_tum

__all__ = [
    "Sequence",
    "SequenceWriter",
    "atomic_write",
    "atomic_write_text",
    "read_depth_png",
    "read_rgb",
    "read_tum",
    "write_tum",
]
