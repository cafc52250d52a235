"""The project's own sequence layout (docs/datasets.md, Sequence layout) as a :class:`SequenceFormat`."""

from __future__ import annotations

from pathlib import Path

from c3f_slam.io import Sequence
from datamodules.formats.base import SequenceFormat


class ProjectFormat(SequenceFormat):
    """``SEQ/rgb/``, ``camera.json``, optional ``depth/``, ``poses.txt``, ``mesh.ply``
    (:class:`c3f_slam.io.Sequence`); ``min_frames``: fewer frames in a sequence is an error."""

    name = "c3f"
    title = "project-layout"
    layout = "<seq>/rgb/*.png + camera.json (optional depth/, poses.txt, mesh.ply)"

    def __init__(self, min_frames: int = 1) -> None:
        self.min_frames = min_frames

    def is_sequence(self, folder: Path) -> bool:
        return (folder / "rgb").is_dir()  # a missing camera.json is an error of open(), not skipped

    def open(self, folder: Path) -> Sequence:
        return Sequence(folder, min_frames=self.min_frames)
