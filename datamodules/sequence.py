"""Data module for the project's own sequence layout (docs/datasets.md, Sequence layout).

``data_dir`` holds sequence folders, each with ``rgb/`` and ``camera.json`` (the simulator
writes exactly this), at any depth below it; a ``data_dir`` that is itself a sequence is used
as a single sequence.
"""

from __future__ import annotations

from datamodules.base import SequenceDataModule
from datamodules.formats.project import ProjectFormat


class C3FSequenceDataModule(SequenceDataModule):
    """Sequences in the project's layout: ``data_dir/<name>/{rgb,depth,camera.json,poses.txt}``."""

    def sequence_format(self) -> ProjectFormat:
        return ProjectFormat(min_frames=self.min_frames)
