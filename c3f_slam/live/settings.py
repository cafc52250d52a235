"""The settings of a live run that are not the run's own (those are the settings tree,
:mod:`c3f_slam.config`): where the page is served, how the source is paced, when the alert fires."""

from __future__ import annotations

from dataclasses import dataclass

from c3f_core.errors import InputError

LOOPBACK = "127.0.0.1"


@dataclass(frozen=True, kw_only=True)
class LiveSettings:
    """``python -m c3f_slam live`` options (docs/live.md); lengths in metres, shares in 0..1."""

    host: str = LOOPBACK  #: address the page is served on (loopback: nothing listens elsewhere)
    port: int = 8765  #: port of the page (0: any free one)
    rate: float | None = None  #: frames per second of the source (None: a video's own, a folder's timestamps)
    as_fast_as_possible: bool = False  #: no pacing: frames come as fast as they decode (tests, benchmarks)
    keep_every_frame: bool = False  #: never drop a frame: the run falls behind the source instead (recordings)
    alert_threshold: float = 0.2  #: a segment left with more unseen wall than this share raises the alert
    alert_margin: float = 0.01  #: the scope has left a segment once this far beyond its ends
    map_voxel: float = 0.003  #: the page's 3D map keeps one point per voxel of this side
    linger: float = 60.0  #: seconds the page keeps showing the final state after the run (Ctrl-C ends it)

    def __post_init__(self) -> None:
        if not 0 <= self.port <= 65535:
            raise InputError(f"--port must be 0..65535, got {self.port}")
        if self.rate is not None and not self.rate > 0:
            raise InputError(f"--rate must be > 0 frames per second, got {self.rate}")
        if not 0 <= self.alert_threshold <= 1:
            raise InputError(f"--alert-threshold must be a share in 0..1, got {self.alert_threshold}")
        if not self.alert_margin >= 0:
            raise InputError(f"--alert-margin must be >= 0 metres, got {self.alert_margin}")
        if not self.map_voxel > 0:
            raise InputError(f"--map-voxel must be > 0 metres, got {self.map_voxel}")
        if not self.linger >= 0:
            raise InputError(f"--linger must be >= 0 seconds, got {self.linger}")
