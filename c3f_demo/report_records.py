"""The records the report's three steps hand on, one way: :func:`c3f_demo.collect.collect` reads a
demo folder into a :class:`ReportData`, :func:`c3f_demo.figures.make_figures` draws a
:class:`Figures` from it, and :func:`c3f_demo.report.build_report` writes the HTML from the two.

Paths of images and videos are relative to the demo folder; their bytes travel with them, so the
HTML step reads no file. Lengths in metres.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath
from typing import Any

import numpy as np


def read_file(path: Path) -> bytes | None:
    """The bytes of ``path``; None when there is no such file."""
    return path.read_bytes() if path.is_file() else None


@dataclass(frozen=True)
class _File:
    """A file by its path in the demo folder."""

    path: str

    @property
    def name(self) -> str:
        return PurePosixPath(self.path).name


@dataclass(frozen=True)
class Image(_File):
    """A PNG; ``png`` None when the file is missing."""

    png: bytes | None = field(default=None, repr=False)

    @classmethod
    def read(cls, root: Path, path: str) -> Image:
        """The file ``root / path``."""
        return cls(path, read_file(root / path))


@dataclass(frozen=True)
class Video(_File):
    """An MP4 with its caption; ``data`` None when the file is missing."""

    caption: str = ""
    data: bytes | None = field(default=None, repr=False)

    @classmethod
    def read(cls, root: Path, path: str, caption: str) -> Video:
        """The file ``root / path``."""
        return cls(path, caption, read_file(root / path))


@dataclass(frozen=True)
class DepthSamples:
    """Evenly spaced frames of the held-out sequence: RGB, true depth and, per column label, the
    prediction times the metric scale its export recorded (``scales``)."""

    frames: list[int]
    rgb: list[np.ndarray]
    true: list[np.ndarray]
    predicted: dict[str, list[np.ndarray]]
    scales: dict[str, float]


@dataclass(frozen=True)
class TissueSample:
    """The tissue mask of run ``run`` (True = tissue) and the sequence's frame ``frame`` under it."""

    run: str
    frame: int
    rgb: np.ndarray
    mask: np.ndarray


@dataclass(frozen=True)
class ViewData:
    """The 3D view of configuration ``run``: the viewer's data at the report's budget. ``folder``:
    its run folder in the demo folder; ``write``: the report writes the view there (the demo), else
    the ``view`` stage did (its ``videos``, or its ``error``)."""

    run: str
    title: str
    folder: str
    write: bool
    data: dict | None = None
    budget_triangles: int = 0
    error: str | None = None
    videos: tuple[Video, ...] = ()


@dataclass(frozen=True)
class ReportData:
    """Everything the report shows, read once (``collect``). ``variant``: ``demo`` or ``video`` (no
    ground truth: ``metrics`` has ``slam`` alone, ``ingest`` is the ingest stage's record). The
    fields after ``images`` are what the figures are drawn from."""

    variant: str
    config: dict
    metrics: dict
    timings: list[tuple[str, float, str]]
    environment: dict[str, str]
    zoo: dict = field(default_factory=dict)
    ttt_guard: dict | None = None
    ingest: dict | None = None
    unseen: dict = field(default_factory=dict)
    view: ViewData | None = None
    images: dict[str, Image] = field(default_factory=dict)
    depth_samples: DepthSamples | None = None
    meshes: dict[str, Any] = field(default_factory=dict)
    coverage: dict[str, Any] = field(default_factory=dict)
    path_points: np.ndarray | None = None
    tissue: TissueSample | None = None
    frame_labels: dict[str, tuple[str, list[str]]] = field(default_factory=dict)


@dataclass(frozen=True)
class ViewFigures:
    """The 3D view's videos, the render time per frame of each (ms) and why there is no view."""

    videos: tuple[Video, ...] = ()
    render_ms: dict[str, float] = field(default_factory=dict)
    error: str | None = None


@dataclass(frozen=True, kw_only=True)
class Figures:
    """Every image of the report by its path (``images``) and what each figure shows: the depth
    samples' colour range and scales, mesh and coverage renders (file names in ``figures/``) per
    configuration, the tissue mask, the frame strips, the 3D view's videos."""

    images: dict[str, Image] = field(default_factory=dict)
    depth: dict = field(default_factory=dict)
    meshes: dict[str, list[str]] = field(default_factory=dict)
    coverage: dict[str, list[str]] = field(default_factory=dict)
    tissue: dict | None = None
    frames: dict[str, dict] = field(default_factory=dict)
    view: ViewFigures = field(default_factory=ViewFigures)

    def image(self, path: str) -> Image:
        """The image at ``path`` (a missing one when there is none)."""
        return self.images.get(path, Image(path))
