"""What the live page shows (:class:`LiveState`): written by the run loop's thread, read by the
server's threads under one lock.

Every mutation bumps one integer ``version`` and stamps what it changed with it, so that
:meth:`LiveState.snapshot` (``since``) returns only what changed after a version a page already
has; ``since=0`` returns everything. Memory stays bounded over a long run except for what grows
with the explored colon: the current frame is the only image kept, delays are the last
:data:`DELAY_SAMPLES` samples, the timeline is run-length encoded, the camera path keeps a point
only every :data:`PATH_STEP_M` of motion; wall rows and map points grow with the map.

Units: metres, seconds (Unix time from ``time.time()`` for ``captured_at``); delays are reported
in ms. Poses are camera-to-world 4x4 (docs/design.md, Conventions).
"""

from __future__ import annotations

import base64
import math
import threading
import time
from bisect import bisect_right
from collections import deque
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from c3f_slam.frames.quality import QUALITY_CAUSES

#: what a back-end did with a taken frame (c3f_slam.pipeline.frame_step.KINDS)
DECISION_KINDS = ("extended", "keyframe", "attached", "lone", "lost")
#: why a taken frame was skipped (c3f_slam.pipeline.run.SKIP_REASONS; "duplicate" is the repeated frame)
SKIP_KINDS = ("black", "saturated", "featureless", "unreadable", *QUALITY_CAUSES)
REJOINED, DROPPED = "rejoined", "dropped"
#: every kind a timeline entry can have
TIMELINE_KINDS = (*DECISION_KINDS, REJOINED, *SKIP_KINDS, DROPPED)
STATUSES = ("running", "finished", "error", "interrupted")
SEGMENT_KEYS = ("index", "start_m", "end_m", "unseen_share", "state")
ALERT_KEYS = ("segment", "start_m", "end_m", "unseen_share")

DELAY_SAMPLES = 2000  #: delays kept per kind (the newest)
MAX_DELAY_S = 3600.0  #: a delay outside [0, this] is ignored (clock trouble, not a delay)
PATH_STEP_M = 1e-3  #: a camera position joins the path when this far from the path's last point
JPEG_QUALITY = 80
OUTSIDE_GAIN = 0.35  #: brightness kept outside the tissue mask on the page's frame
OUTLINE_RGB = (90, 200, 255)  #: the tissue mask's outline on the page's frame


@dataclass(frozen=True, eq=False)
class WallRow:
    """One ring of the unseen-wall grid: row ``i`` along the centreline (from 0; arc length of its
    centre (i + 0.5) x cell length), its ``centre`` (3,) metres and the unit vectors ``N``, ``B``
    (3,) of its frame. Cell j of A is at theta_j = -pi + (j + 0.5) 2 pi / A; its wall point is
    centre + radius_j (cos(theta_j) N + sin(theta_j) B). ``radius`` (A,) metres (NaN: unknown),
    ``observed`` / ``measured`` (A,) bool, ``colour`` (A, 3) uint8 RGB (the wall's mean colour where
    measured). The arrays are copied (read-only) on construction."""

    i: int
    centre: np.ndarray
    N: np.ndarray
    B: np.ndarray
    radius: np.ndarray
    observed: np.ndarray
    measured: np.ndarray
    colour: np.ndarray

    def __post_init__(self) -> None:
        if int(self.i) != self.i or self.i < 0:
            raise ValueError(f"wall row index must be an integer >= 0, got {self.i!r}")
        fields = {"i": int(self.i)}
        for name in ("centre", "N", "B"):
            fields[name] = np.array(getattr(self, name), dtype=np.float64).reshape(-1)
            if fields[name].shape != (3,):
                raise ValueError(f"wall row {self.i}: {name} must have 3 values, got {fields[name].size}")
        fields["radius"] = np.array(self.radius, dtype=np.float64).reshape(-1)
        a = fields["radius"].size
        for name in ("observed", "measured"):
            fields[name] = np.array(self.observed if name == "observed" else self.measured, dtype=bool).reshape(-1)
            if fields[name].size != a:
                raise ValueError(f"wall row {self.i}: {name} has {fields[name].size} cells, radius {a}")
        fields["colour"] = np.array(self.colour)
        if fields["colour"].shape != (a, 3) or fields["colour"].dtype != np.uint8:
            raise ValueError(f"wall row {self.i}: colour must be ({a}, 3) uint8, got {fields['colour'].shape} "
                             f"{fields['colour'].dtype}")
        for name, value in fields.items():
            if isinstance(value, np.ndarray):
                value.flags.writeable = False
            object.__setattr__(self, name, value)

    def to_json(self, version: int) -> dict:
        """The row as the page reads it (see :meth:`LiveState.snapshot`)."""
        radius = np.round(self.radius, 5).tolist()
        return {"i": self.i, "version": version,
                "centre": [round(float(x), 6) for x in self.centre], "N": [round(float(x), 6) for x in self.N],
                "B": [round(float(x), 6) for x in self.B],
                "radius": [None if math.isnan(r) or math.isinf(r) else r for r in radius],
                "observed": "".join("1" if b else "0" for b in self.observed.tolist()),
                "measured": "".join("1" if b else "0" for b in self.measured.tolist()),
                "colour": _b64(self.colour)}


@dataclass(frozen=True)
class FrameJpeg:
    """The current frame as the page shows it: JPEG ``data``, the state ``version`` that set the image,
    its frame ``index``, ``captured_at`` (Unix seconds) and timeline ``decision``."""

    version: int
    data: bytes
    index: int
    captured_at: float
    decision: str


class _Row:
    __slots__ = ("row", "version", "json")

    def __init__(self, row: WallRow, version: int) -> None:
        self.row, self.version, self.json = row, version, None


class _Chunk:
    __slots__ = ("version", "xyz", "rgb", "b64")

    def __init__(self, version: int, xyz: np.ndarray, rgb: np.ndarray) -> None:
        self.version, self.xyz, self.rgb, self.b64 = version, xyz, rgb, None


def _b64(a: np.ndarray) -> str:
    return base64.b64encode(np.ascontiguousarray(a).tobytes()).decode("ascii")


def _plain(obj: object) -> object:
    """``obj`` with NumPy values, tuples and paths made JSON types; non-finite floats become None."""
    if isinstance(obj, dict):
        return {str(k): _plain(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_plain(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _plain(obj.tolist())
    if isinstance(obj, np.generic):
        return _plain(obj.item())
    if isinstance(obj, bool | int | str) or obj is None:
        return obj
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, Path):
        return str(obj)
    return str(obj)


def _stats_ms(samples: list[float], scale: float) -> dict:
    if not samples:
        return {"median": None, "p95": None, "samples": 0}
    med, p95 = np.percentile(np.asarray(samples) * scale, [50, 95])
    return {"median": round(float(med), 1), "p95": round(float(p95), 1), "samples": len(samples)}


def _check_kind(kind: str) -> str:
    if kind not in TIMELINE_KINDS:
        raise ValueError(f"unknown frame kind {kind!r} (one of {', '.join(TIMELINE_KINDS)})")
    return kind


class LiveState:
    """The store of a live run's page (module docstring). Producer methods: ``publish_frame``,
    ``drop_frames``, ``update_wall``, ``reset_wall``, ``set_segments``, ``add_alert``,
    ``add_map_points``, ``set_rates``, ``finish``; reader methods: ``snapshot``, ``frame_jpeg``,
    ``current_jpeg``, ``report_shown``, ``sizes``."""

    def __init__(self, *, source: dict, camera: dict, tissue_mask: np.ndarray | None, wall: dict) -> None:
        self._lock = threading.Lock()
        self._encode_lock = threading.Lock()  # one JPEG encoding at a time (the others then use its result)
        self._source = _plain(dict(source))
        self._camera = _plain(dict(camera))
        self._wall_settings = _plain(dict(wall))
        self._angle_bins = int(wall["angle_bins"])
        self._mask = None if tissue_mask is None else np.asarray(tissue_mask, dtype=bool)
        if self._mask is not None and self._mask.ndim != 2:
            raise ValueError(f"tissue_mask must be (H, W) bool, got shape {self._mask.shape}")
        self._overlay: tuple[tuple[int, int], np.ndarray, tuple] | None = None  # (shape, mask u8, contours)
        self._version = 0
        self._status, self._error, self._summary = "running", None, None
        self._frame: dict | None = None  # the record of the frame whose image is kept
        self._image: np.ndarray | None = None
        self._jpeg: FrameJpeg | None = None
        self._latest_index: int | None = None
        self._pose: list[float] | None = None
        self._pose_index: int | None = None
        self._publish_delays: deque[float] = deque(maxlen=DELAY_SAMPLES)  # seconds
        self._display_delays: deque[float] = deque(maxlen=DELAY_SAMPLES)  # ms
        self._rates = {"source_fps": None, "processed_fps": None, "dropped": 0, "taken": 0}
        self._timeline: list[list] = []  # [first, last, kind, version]
        self._path: list[list[float]] = []
        self._path_versions: list[int] = []
        self._rows: dict[int, _Row] = {}  # ordered by version (a replaced row moves to the end)
        self._chunks: list[_Chunk] = []
        self._map_count = 0
        self._epoch, self._reset_version, self._reset_reason = 0, 0, None
        self._segments: list[dict] = []
        self._alerts: list[dict] = []

    # -- producer -------------------------------------------------------------------------------

    def _bump(self) -> int:
        self._version += 1
        return self._version

    def _append_timeline(self, first: int, last: int, kind: str, version: int) -> None:
        tail = self._timeline[-1] if self._timeline else None
        if tail is not None and tail[2] == kind and first == tail[1] + 1:
            tail[1], tail[3] = last, version
        else:
            self._timeline.append([first, last, kind, version])
        self._latest_index = last if self._latest_index is None else max(self._latest_index, last)

    def publish_frame(self, *, index: int, timestamp: float, captured_at: float, decision: str,
                      rgb: np.ndarray | None, pose: np.ndarray | None) -> None:
        """A frame the run took: stream ``index``, its ``timestamp`` (s), ``captured_at`` (Unix s, when
        the source delivered it), the timeline ``decision``, its ``rgb`` (H, W, 3) uint8 (None:
        unreadable; kept by reference: do not write into it afterwards) and camera-to-world ``pose``
        (4x4 metres; None: not placed)."""
        _check_kind(decision)
        if rgb is not None and (rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8):
            raise ValueError(f"frame {index}: rgb must be (H, W, 3) uint8, got {rgb.shape} {rgb.dtype}")
        position = None
        if pose is not None:
            pose = np.asarray(pose, dtype=np.float64).reshape(4, 4)
            position = pose[:3, 3].tolist()
            pose = [float(x) for x in pose.reshape(-1)]
        now = time.time()
        delay = now - float(captured_at)
        with self._lock:
            v = self._bump()
            if 0 <= delay <= MAX_DELAY_S:
                self._publish_delays.append(delay)
            self._append_timeline(int(index), int(index), decision, v)
            if pose is not None:
                self._pose, self._pose_index = pose, int(index)
                last = self._path[-1] if self._path else None
                if last is None or math.dist(last, position) >= PATH_STEP_M:
                    self._path.append(position)
                    self._path_versions.append(v)
            if rgb is not None:
                self._image = rgb
                self._frame = {"index": int(index), "timestamp": float(timestamp), "captured_at": float(captured_at),
                               "published_at": now, "decision": decision, "version": v}

    def drop_frames(self, first_index: int, last_index: int) -> None:
        """Frames ``first_index``..``last_index`` (inclusive) the source delivered and the run dropped."""
        if last_index < first_index:
            raise ValueError(f"drop_frames: last index {last_index} before first index {first_index}")
        with self._lock:
            self._append_timeline(int(first_index), int(last_index), DROPPED, self._bump())

    def update_wall(self, rows: list[WallRow]) -> None:
        """New or changed rows of the unseen-wall grid; a row sent again replaces the earlier one."""
        for row in rows:
            if not isinstance(row, WallRow):
                raise TypeError(f"update_wall takes WallRow items, got {type(row).__name__}")
            if row.radius.size != self._angle_bins:
                raise ValueError(f"wall row {row.i} has {row.radius.size} cells, the grid {self._angle_bins}")
        if not rows:
            return
        with self._lock:
            v = self._bump()
            for row in rows:
                self._rows.pop(row.i, None)
                self._rows[row.i] = _Row(row, v)

    def reset_wall(self, reason: str) -> None:
        """The map restarted (``reason``, shown on the page): the wall rows, map points, camera path,
        pose and segments so far are discarded; pages learn it from ``wall.reset``."""
        with self._lock:
            v = self._bump()
            self._rows.clear()
            self._chunks.clear()
            self._map_count = 0
            self._path.clear()
            self._path_versions.clear()
            self._pose = self._pose_index = None
            self._segments = []
            self._epoch += 1
            self._reset_version, self._reset_reason = v, str(reason)

    def set_segments(self, segments: list[dict]) -> None:
        """The whole list of segments: ``index``, ``start_m``, ``end_m``, ``unseen_share`` (0..1),
        ``state`` ("passed" | "current")."""
        for seg in segments:
            missing = [k for k in SEGMENT_KEYS if k not in seg]
            if missing:
                raise ValueError(f"segment without {', '.join(missing)}: {seg!r}")
        plain = _plain(list(segments))
        with self._lock:
            self._bump()
            self._segments = plain

    def add_alert(self, alert: dict) -> None:
        """A segment left with too much unseen wall: ``segment``, ``start_m``, ``end_m``,
        ``unseen_share``, ``gap`` (``clock`` 1..12, ``s_from_m``, ``s_to_m``, ``area_cm2``),
        ``frame``, ``time``. Alerts are all kept."""
        missing = [k for k in ALERT_KEYS if k not in alert]
        if missing:
            raise ValueError(f"alert without {', '.join(missing)}: {alert!r}")
        plain = _plain(dict(alert))
        with self._lock:
            plain["version"] = self._bump()
            self._alerts.append(plain)

    def add_map_points(self, xyz: np.ndarray, rgb: np.ndarray) -> None:
        """New points of the 3D map: ``xyz`` (n, 3) world metres, ``rgb`` (n, 3) uint8; non-finite
        points are left out."""
        xyz = np.asarray(xyz, dtype=np.float32).reshape(-1, 3)
        rgb = np.asarray(rgb).reshape(-1, 3)
        if rgb.dtype != np.uint8 or len(rgb) != len(xyz):
            raise ValueError(f"map points: rgb must be ({len(xyz)}, 3) uint8, got {rgb.shape} {rgb.dtype}")
        keep = np.isfinite(xyz).all(axis=1)
        xyz, rgb = np.ascontiguousarray(xyz[keep]), np.ascontiguousarray(rgb[keep])
        if not len(xyz):
            return
        with self._lock:
            self._chunks.append(_Chunk(self._bump(), xyz, rgb))
            self._map_count += len(xyz)

    def set_rates(self, *, source_fps: float | None, processed_fps: float | None, dropped: int, taken: int) -> None:
        """Frames per second the source delivers and the run processes (None: unknown), frames dropped
        and taken so far."""
        rates = {"source_fps": _plain(None if source_fps is None else float(source_fps)),
                 "processed_fps": _plain(None if processed_fps is None else float(processed_fps)),
                 "dropped": int(dropped), "taken": int(taken)}
        with self._lock:
            self._bump()
            self._rates = rates

    def finish(self, status: str, error: str | None = None, summary: dict | None = None) -> None:
        """The run ended: ``status`` "finished" / "error" / "interrupted", the one-line ``error``, the
        run folder's headline numbers ``summary``."""
        if status not in STATUSES[1:]:
            raise ValueError(f"unknown final status {status!r} (one of {', '.join(STATUSES[1:])})")
        plain = None if summary is None else _plain(dict(summary))
        with self._lock:
            self._bump()
            self._status, self._error, self._summary = status, None if error is None else str(error), plain

    # -- readers --------------------------------------------------------------------------------

    @property
    def version(self) -> int:
        with self._lock:
            return self._version

    def report_shown(self, index: int, delay_ms: float) -> None:
        """A page displayed frame ``index`` ``delay_ms`` after its capture (ignored outside 0 ms..1 h)."""
        delay_ms = float(delay_ms)
        if not 0 <= delay_ms <= MAX_DELAY_S * 1000:
            return
        with self._lock:
            self._bump()
            self._display_delays.append(delay_ms)

    def snapshot(self, since: int = 0) -> dict:
        """What changed after version ``since`` (everything for 0, or for a ``since`` this state never
        had), JSON-able:

        - ``version``: the state's version (the page's next ``since``); ``full``: this answer holds
          everything (a page drops what it kept first);
        - ``status`` ("running" | "finished" | "error" | "interrupted"), ``error`` (str | None),
          ``summary`` (dict | None), ``source``, ``camera``, ``wall_settings``: as given;
        - ``latest_index``: the newest frame index taken or dropped (None before any);
        - ``frame``: the frame /frame.jpg shows (the newest with an image): ``index``,
          ``timestamp`` (s), ``captured_at`` / ``published_at`` (Unix s), ``decision``, ``version``
          (the state version that set the image: /frame.jpg?v=...); None before the first;
        - ``pose``: the newest camera-to-world pose (16 floats, row-major, metres; kept across frames
          without one, None after a reset); ``pose_index``: its frame;
        - ``rates``: ``source_fps``, ``processed_fps`` (None: unknown), ``dropped``, ``taken``,
          ``dropped_share`` (None before any), ``delays``: ``capture_to_publish_ms`` and
          ``capture_to_display_ms``, each ``{median, p95, samples}`` (ms; None without samples);
        - ``path``: ``{start, points}``: camera positions [x, y, z] (metres, one per PATH_STEP_M of
          motion); ``start`` is the position of the first one in the whole path: a page cuts its
          list to ``start`` and appends;
        - ``wall``: ``{epoch, reset, reason, rows}``: ``epoch`` counts resets, ``reset``: the map
          restarted after ``since`` (drop the rows kept before applying these), ``reason`` of the
          last reset (None before any); ``rows``: those changed after ``since``, each ``{i, version,
          centre, N, B, radius, observed, measured, colour}``: vectors as 3 floats, ``radius`` A floats
          (metres; null: unknown), ``observed`` / ``measured`` strings of A "0"/"1", ``colour`` base64
          of A x 3 uint8 RGB;
        - ``map``: ``{start, count, xyz, rgb}``: the points added after ``since``, ``xyz`` base64 of
          little-endian float32 (n, 3) metres, ``rgb`` base64 of uint8 (n, 3); ``start`` their offset
          in the whole map (cut to it, then append), ``count`` the map's size;
        - ``segments``: the whole list as set; ``alerts``: all alerts, oldest first (each with the
          ``version`` that added it);
        - ``timeline``: ``{start, entries}``: run-length entries [first_index, last_index, kind] changed
          after ``since``; ``start`` the position of the first in the whole timeline (cut, append).
        """
        with self._lock:
            version = self._version
            full = since <= 0 or since > version
            since = 0 if full else int(since)
            start = len(self._timeline)
            while start > 0 and self._timeline[start - 1][3] > since:
                start -= 1
            timeline = [e[:3] for e in self._timeline[start:]]
            path_start = bisect_right(self._path_versions, since)
            path = self._path[path_start:]
            rows = []
            for rec in reversed(self._rows.values()):
                if rec.version <= since:
                    break
                rows.append(rec)
            first = len(self._chunks)
            while first > 0 and self._chunks[first - 1].version > since:
                first -= 1
            chunks = self._chunks[first:]
            out = {"version": version, "full": full, "status": self._status, "error": self._error,
                   "summary": self._summary, "source": self._source, "camera": self._camera,
                   "wall_settings": self._wall_settings, "latest_index": self._latest_index,
                   "frame": None if self._frame is None else dict(self._frame), "pose": self._pose,
                   "pose_index": self._pose_index, "segments": list(self._segments), "alerts": list(self._alerts)}
            rates = dict(self._rates)
            publish, display = list(self._publish_delays), list(self._display_delays)
            wall = {"epoch": self._epoch, "reset": since < self._reset_version, "reason": self._reset_reason}
            map_count = self._map_count
        # the serialisation runs outside the lock (stored rows and chunks are never changed in place)
        n = rates["dropped"] + rates["taken"]
        rates["dropped_share"] = rates["dropped"] / n if n else None
        rates["delays"] = {"capture_to_publish_ms": _stats_ms(publish, 1000.0),
                           "capture_to_display_ms": _stats_ms(display, 1.0)}
        out["rates"] = rates
        out["path"] = {"start": path_start, "points": [[round(x, 5) for x in p] for p in path]}
        for rec in rows:
            if rec.json is None:
                rec.json = rec.row.to_json(rec.version)
        wall["rows"] = [rec.json for rec in reversed(rows)]
        out["wall"] = wall
        for c in chunks:
            if c.b64 is None:  # 12 and 3 bytes a point: the base64 of consecutive chunks concatenate
                c.b64 = (_b64(c.xyz.astype("<f4", copy=False)), _b64(c.rgb))
        sent = sum(len(c.xyz) for c in chunks)
        out["map"] = {"start": map_count - sent, "count": map_count, "xyz": "".join(c.b64[0] for c in chunks),
                      "rgb": "".join(c.b64[1] for c in chunks)}
        out["timeline"] = {"start": start, "entries": timeline}
        return out

    def current_jpeg(self) -> FrameJpeg | None:
        """The current frame as JPEG with the tissue mask shown (outside darkened, outline drawn),
        encoded once per frame; None before the first frame."""
        with self._lock:
            if self._image is None:
                return None
            rgb, record, cached = self._image, self._frame, self._jpeg
        if cached is not None and cached.version == record["version"]:
            return cached
        with self._encode_lock:
            with self._lock:
                cached = self._jpeg
            if cached is not None and cached.version == record["version"]:
                return cached
            ok, buf = cv2.imencode(".jpg", self._overlaid(rgb), [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
            if not ok:
                raise RuntimeError(f"frame {record['index']}: JPEG encoding failed")
            result = FrameJpeg(version=record["version"], data=buf.tobytes(), index=record["index"],
                               captured_at=record["captured_at"], decision=record["decision"])
            with self._lock:
                if self._jpeg is None or self._jpeg.version < result.version:
                    self._jpeg = result
            return result

    def frame_jpeg(self) -> tuple[int, bytes] | None:
        """(frame version, JPEG bytes) of the current frame (:meth:`current_jpeg`); None before the first."""
        jpeg = self.current_jpeg()
        return None if jpeg is None else (jpeg.version, jpeg.data)

    def _overlaid(self, rgb: np.ndarray) -> np.ndarray:
        """BGR of ``rgb`` with the outside of the tissue mask darkened and the mask's outline drawn."""
        bgr = cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)
        if self._mask is None:
            return bgr
        shape = rgb.shape[:2]
        if self._overlay is None or self._overlay[0] != shape:
            mask = self._mask
            if mask.shape != shape:
                mask = cv2.resize(mask.astype(np.uint8), (shape[1], shape[0]), interpolation=cv2.INTER_NEAREST) > 0
            mask_u8 = mask.astype(np.uint8) * 255
            contours = () if mask.all() else cv2.findContours(mask_u8, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)[0]
            self._overlay = (shape, mask_u8, tuple(contours))
        _, mask_u8, contours = self._overlay
        out = cv2.convertScaleAbs(bgr, alpha=OUTSIDE_GAIN)
        cv2.copyTo(bgr, mask_u8, out)
        if contours:
            thickness = max(1, round(max(shape) / 400))
            cv2.drawContours(out, list(contours), -1, OUTLINE_RGB[::-1], thickness, cv2.LINE_AA)
        return out

    def sizes(self) -> dict[str, int]:
        """How many items the state keeps (diagnostics): delay samples, timeline entries, path points,
        wall rows, map points and chunks, alerts, images."""
        with self._lock:
            return {"publish_delays": len(self._publish_delays), "display_delays": len(self._display_delays),
                    "timeline": len(self._timeline), "path": len(self._path), "wall_rows": len(self._rows),
                    "map_points": self._map_count, "map_chunks": len(self._chunks), "alerts": len(self._alerts),
                    "images": int(self._image is not None)}
