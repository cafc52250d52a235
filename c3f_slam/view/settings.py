"""Settings of ``python -m c3f_slam view OUT``: the tree :class:`ViewSettings` (the page's
triangle budget, the videos' encoding, the fly-through's camera) and its
:class:`~c3f_core.settings_cli.SettingsSpec` :data:`VIEW_SETTINGS` (``--config``, ``--set
part.field=value``, ``--print-config``; one preset, ``default``).

Defaults live only in these dataclasses; each group checks itself (one InputError naming
``part.field``). ``view`` records the tree it used in ``OUT/view.json`` under ``settings``, so
``view OUT --config OUT/view.json`` replays it. A light module (no Open3D): ``--print-config``
imports it alone.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from c3f_core.errors import InputError
from c3f_core.settings_cli import SettingsSpec

BYTES_PER_TRIANGLE = 26  #: base64 page bytes per triangle of a typical TSDF mesh (measured, docs/view.md)


def _check(ok: bool, message: str) -> None:
    if not ok:
        raise InputError(message)


def _in_range(group: str, obj: object, name: str, low: float, high: float, low_open: bool = False) -> None:
    """InputError naming ``group.name`` unless its value is a number with ``low <= value <= high``
    (``low < value`` when ``low_open``)."""
    value = getattr(obj, name)
    ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value) \
        and (low < value if low_open else low <= value) and value <= high
    _check(ok, f"{group}.{name} must be in {'(' if low_open else '['}{low:g}, {high:g}], got {value!r}")


def _int_in(group: str, obj: object, name: str, low: int, high: int) -> None:
    """InputError naming ``group.name`` unless its value is an integer in ``[low, high]``."""
    value = getattr(obj, name)
    _check(isinstance(value, int) and not isinstance(value, bool) and low <= value <= high,
           f"{group}.{name} must be an integer in [{low}, {high}], got {value!r}")


@dataclass(frozen=True)
class ViewBudget:
    """Triangles per mesh layer of a page: above its budget a mesh is decimated (the page links
    the full-resolution file)."""

    surface: int = 150_000  #: triangles of the reconstruction (mesh.ply)
    unseen: int = 30_000  #: triangles of the unseen wall patches (unseen.ply)
    gt_surface: int = 50_000  #: triangles of the ground-truth surface near the true path
    components: int = 20_000  #: triangles of all the components (components/NN/) together

    def __post_init__(self) -> None:
        for name in ("surface", "unseen", "gt_surface", "components"):
            _int_in("budget", self, name, 1, 100_000_000)

    @property
    def triangles(self) -> int:
        """All the layers' budgets together (triangles)."""
        return self.surface + self.unseen + self.gt_surface + self.components

    @property
    def approx_mb(self) -> float:
        """Page geometry at the full budget, MB (1e6 bytes)."""
        return self.triangles * BYTES_PER_TRIANGLE / 1e6


#: the demo report's budget (``report.html`` embeds the viewer: at most 105,000 triangles, about 3 MB)
REPORT_BUDGET = ViewBudget(surface=60_000, unseen=15_000, gt_surface=20_000, components=10_000)


@dataclass(frozen=True)
class VideoSettings:
    """How rerender.mp4 and flythrough.mp4 are encoded (H.264, libx264)."""

    fps: float = 30.0  #: frames per second of both videos
    crf: int = 23  #: x264 constant rate factor, 0..51 (lower: better and larger)

    def __post_init__(self) -> None:
        _in_range("video", self, "fps", 0, 240, low_open=True)
        _int_in("video", self, "crf", 0, 51)


@dataclass(frozen=True)
class FlythroughSettings:
    """flythrough.mp4: a camera gliding along the smoothed camera path."""

    width: int = 384  #: frame width (pixels)
    height: int = 288  #: frame height (pixels)
    fov_deg: float = 100.0  #: horizontal field of view (degrees)
    frames: int = 240  #: frames of the video (8 s at 30 frames/s)
    smooth_share: float = 0.03  #: Gaussian sigma of the path smoothing, as a share of the path length (0..1]
    samples: int = 600  #: arc-length samples of the path before smoothing

    def __post_init__(self) -> None:
        for name, low, high in (("width", 16, 8192), ("height", 16, 8192), ("frames", 2, 1_000_000),
                                ("samples", 10, 1_000_000)):
            _int_in("flythrough", self, name, low, high)
        _in_range("flythrough", self, "fov_deg", 0, 170, low_open=True)
        _in_range("flythrough", self, "smooth_share", 0, 1, low_open=True)


@dataclass(frozen=True)
class ViewSettings:
    """The settings of ``python -m c3f_slam view`` (sizes in pixels, angles in degrees)."""

    budget: ViewBudget = field(default_factory=ViewBudget)  #: triangles per layer of view.html
    video: VideoSettings = field(default_factory=VideoSettings)  #: encoding of both videos
    flythrough: FlythroughSettings = field(default_factory=FlythroughSettings)  #: the fly-through's camera


#: the view's settings: one preset, replayed from the ``settings`` of an earlier view's view.json
VIEW_SETTINGS: SettingsSpec[ViewSettings] = SettingsSpec(
    presets={"default": ViewSettings}, record_key="settings",
    usage="python -m c3f_slam view OUT --config THIS_FILE")

__all__ = ["BYTES_PER_TRIANGLE", "REPORT_BUDGET", "VIEW_SETTINGS", "FlythroughSettings", "VideoSettings",
           "ViewBudget", "ViewSettings"]
