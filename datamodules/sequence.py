"""Data module for the project's own sequence layout (SPEC §5.2).

``data_dir`` holds one folder per sequence, each with ``rgb/`` and ``camera.json`` (the
simulator writes exactly this). A ``data_dir`` that is itself a sequence is used as a
single sequence.
"""

from __future__ import annotations

from pathlib import Path

from c3f_slam.io import Sequence
from datamodules.base import SequenceDataModule


class C3FSequenceDataModule(SequenceDataModule):
    """Sequences in the project's layout: ``data_dir/<name>/{rgb,depth,camera.json,poses.txt}``."""

    def find_sequences(self) -> list[Path]:
        if (self.data_dir / "rgb").is_dir():
            return [self.data_dir]
        return sorted(p for p in self.data_dir.iterdir() if p.is_dir() and (p / "rgb").is_dir())

    def open_sequence(self, path: Path) -> Sequence:
        return Sequence(path, min_frames=self.hparams.min_frames)
