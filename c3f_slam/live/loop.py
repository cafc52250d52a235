"""The live run: ``run``'s pipeline fed by a paced source, followed frame by frame for the page.

:func:`run_live` is :func:`c3f_slam.pipeline.run.run_slam` with a :class:`LiveRun` as its
observer. The loop stays the run's own (one frame at a time, the same back-end and outputs);
after each frame taken, :meth:`LiveRun.stepped`:

1. hands the frames the source dropped meanwhile to the timeline (:mod:`.source`: newest frame wins);
2. when the back-end placed the frame in the main map, updates the unseen wall with its depth
   and its pose now (:class:`~c3f_slam.coverage.incremental.IncrementalWall`), the 3D map (one
   point per ``map_voxel``) and the segment watch, whose alerts go to the page and to stderr;
   when another component becomes the main map (after a tracking loss) the wall starts again;
3. publishes the frame, its outcome and the rates to the page's store (:mod:`.state`).

At the end (also on errors and Ctrl-C) the wall's last rows are made, the last alerts judged,
and ``live.json`` is written into the run folder beside ``run``'s outputs: the source and its
pacing, frames delivered, taken and dropped, the delays, the unseen-wall update cost against
the length mapped, the live estimate's final shares, and the alerts.
"""

from __future__ import annotations

import socket
import sys
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from c3f_core.errors import InputError
from c3f_slam.config import SlamConfig
from c3f_slam.coverage.incremental import IncrementalWall, voxel_keys
from c3f_slam.frames.stream import FrameStream, StreamFrame
from c3f_slam.io.run_outputs import RunOutputs, write_json
from c3f_slam.live.alerts import SegmentWatch
from c3f_slam.live.server import LiveServer
from c3f_slam.live.settings import LiveSettings
from c3f_slam.live.source import PacedSource
from c3f_slam.live.state import LiveState, WallRow
from c3f_slam.pipeline.frame_step import FrameDecision
from c3f_slam.pipeline.perception import PerceivedFrame
from c3f_slam.pipeline.run import SlamRun, run_slam
from c3f_slam.pipeline.sources import RunInputs

LIVE_JSON = "live.json"
#: the unseen-wall update cost is summarised per this many metres of centreline mapped
COST_BIN_M = 0.05


def _runs(indices: list[int]) -> list[tuple[int, int]]:
    """Consecutive stream indices as (first, last) runs."""
    out: list[tuple[int, int]] = []
    for i in indices:
        if out and i == out[-1][1] + 1:
            out[-1] = (out[-1][0], i)
        else:
            out.append((i, i))
    return out


class UpdateCost:
    """Seconds per unseen-wall update, summarised per ``COST_BIN_M`` of centreline already mapped
    (grows with the colon, not with the frames)."""

    def __init__(self) -> None:
        self.bins: dict[int, list[float]] = {}  # bin -> [count, total, max, sum of rows in reach]

    def add(self, length_m: float, seconds: float, rows: int) -> None:
        b = self.bins.setdefault(int(length_m // COST_BIN_M), [0, 0.0, 0.0, 0])
        b[0] += 1
        b[1] += seconds
        b[2] = max(b[2], seconds)
        b[3] += rows

    def as_list(self) -> list[dict]:
        return [{"mapped_from_m": k * COST_BIN_M, "mapped_to_m": (k + 1) * COST_BIN_M, "updates": int(c),
                 "mean_ms": 1e3 * t / c, "max_ms": 1e3 * m, "mean_rows_changed": r / c}
                for k, (c, t, m, r) in sorted(self.bins.items())]


#: map parts whose live wall is kept (the most recently used); an older part's is forgotten
MAX_TRACKS = 4


@dataclass
class WallTrack:
    """The live wall of one map part (a component of the map), its segment watch, and the points
    of the page's 3D map in it (one per ``map_voxel``)."""

    wall: IncrementalWall
    watch: SegmentWatch
    keys: set[int] = field(default_factory=set)
    points: list[tuple[np.ndarray, np.ndarray]] = field(default_factory=list)

    def new_points(self, xyz: np.ndarray, rgb: np.ndarray, voxel: float) -> tuple[np.ndarray, np.ndarray]:
        """The points of voxels this part has no point in yet (kept, and returned)."""
        if not len(xyz):
            return xyz.astype(np.float32), rgb
        keys, first = np.unique(voxel_keys(xyz, voxel), return_index=True)
        fresh = [n for n, k in zip(first.tolist(), keys.tolist()) if k not in self.keys]
        self.keys.update(keys.tolist())
        out = xyz[fresh].astype(np.float32), rgb[fresh]
        if len(fresh):
            self.points.append(out)
        return out


class LiveRun:
    """The observer of a live run (:class:`c3f_slam.pipeline.run.RunObserver`): paces the source,
    keeps the unseen wall, serves the page. ``echo`` prints a line for the person at the console."""

    def __init__(self, settings: LiveSettings, cfg: SlamConfig,
                 echo: Callable[[str], None] = lambda line: print(line, file=sys.stderr, flush=True)) -> None:
        self.settings, self.cfg, self.echo = settings, cfg, echo
        self.source: PacedSource | None = None
        self.state: LiveState | None = None
        self.server: LiveServer | None = None
        self.tracks: dict[int, WallTrack] = {}  #: per map part (its component), the newest last
        self.key = -1  #: the map part of the last placed frame
        self.switches = 0  #: times the page's wall changed map part
        self.taken = 0
        self.t_first: float | None = None
        self.cost = UpdateCost()
        self._wall_args: tuple | None = None
        self.out: Path | None = None  #: the run folder (where it is published)

    # ------------------------------------------------------------------ the run's hooks
    def frames(self, stream: FrameStream) -> Iterable[StreamFrame]:
        s = self.settings
        self.source = PacedSource(stream, rate=s.rate, as_fast_as_possible=s.as_fast_as_possible,
                                  drop=not s.keep_every_frame)
        return self.source

    def opened(self, run: SlamRun) -> None:
        cfg, sources = run.cfg, run.sources
        cam = sources.camera
        mask = None if sources.tissue.whole_frame else sources.tissue.pixels
        near, far = cfg.coverage.depth_range(cfg.fusion.tsdf.depth_min, cfg.fusion.tsdf.depth_max)
        self._wall_args = (cfg.coverage, cam.K, (near, far), mask)
        assert self.source is not None
        self.state = LiveState(
            source=self.source.describe(),
            camera={"K": np.asarray(cam.K).tolist(), "width": cam.width, "height": cam.height},
            tissue_mask=mask,
            wall={"cell_length_m": cfg.coverage.cell_length, "angle_bins": cfg.coverage.angle_bins,
                  "segment_m": cfg.coverage.segment, "threshold": self.settings.alert_threshold})
        self.server = LiveServer(self.state, self.settings.host, self.settings.port).start()
        self.echo(f"live: {self.server.url} (the page; Ctrl-C ends the run and writes its folder)")

    def stepped(self, run: SlamRun, item: PerceivedFrame, outcome: str, decision: FrameDecision | None) -> None:
        assert self.source is not None and self.state is not None
        frame, state = item.frame, self.state
        now = time.time()
        captured = self.source.captured_at(frame.index) or now
        self.t_first = self.t_first or now
        self.taken += 1
        for first, last in _runs(self.source.take_dropped()):
            state.drop_frames(first, last)
        placed = run.backend.map.current_placement() if decision is not None and decision.fragment >= 0 else None
        pose = None
        if placed is not None and item.depth is not None:
            key, pose = placed
            if key != self.key:
                self._switch(key, frame.index)
            self._update_wall(pose, item, now)
        kind = "rejoined" if decision is not None and decision.rejoined else outcome
        state.publish_frame(index=frame.index, timestamp=frame.timestamp, captured_at=captured, decision=kind,
                            rgb=frame.rgb, pose=pose)
        span = now - self.t_first
        state.set_rates(source_fps=self.source.delivery_rate(),
                        processed_fps=(self.taken - 1) / span if span > 0 else None,
                        dropped=self.source.dropped, taken=self.taken)

    def finished(self, outputs: RunOutputs, summary: dict) -> None:
        try:
            self._finish(outputs, summary)
        except Exception as exc:  # the run's own outputs stay valid
            summary.setdefault("live_error", f"{type(exc).__name__}: {exc}")

    # ------------------------------------------------------------------ parts
    @property
    def track(self) -> WallTrack | None:
        """The wall the page shows: the map part of the last placed frame."""
        return self.tracks.get(self.key)

    def _switch(self, key: int, index: int) -> None:
        """The placed frames moved to map part ``key`` (a tracking loss started a new one, or a
        rejoin merged into an earlier one): the page's wall and map become that part's."""
        assert self._wall_args is not None and self.state is not None
        known = key in self.tracks
        if not known:
            self.tracks[key] = WallTrack(IncrementalWall(*self._wall_args), SegmentWatch(
                self.cfg.coverage.segment, self.settings.alert_threshold, self.settings.alert_margin))
            while len(self.tracks) > MAX_TRACKS:
                self.tracks.pop(next(iter(self.tracks)))
        else:
            self.tracks[key] = self.tracks.pop(key)  # the newest last
        first = self.key == -1
        self.key = key
        if first:
            return
        self.switches += 1
        reason = (f"frame {index} is in an earlier map part (a rejoin): its wall is shown again" if known else
                  f"tracking was lost before frame {index}: a new map part starts, its wall is shown")
        self.state.reset_wall(reason)
        track = self.tracks[key]
        if track.wall.n_rows:
            self.state.update_wall(self._wall_rows(np.arange(track.wall.n_rows)))
        self.state.set_segments(self._segments())
        if track.points:
            self.state.add_map_points(np.concatenate([p for p, _ in track.points]),
                                      np.concatenate([c for _, c in track.points]))
        self.echo(f"live: {reason}")

    def _update_wall(self, pose: np.ndarray, item: PerceivedFrame, now: float) -> None:
        track, state = self.track, self.state
        assert track is not None and state is not None
        wall = track.wall
        t0 = time.perf_counter()
        up = wall.add_frame(pose, item.depth, item.frame.rgb)
        rows = self._wall_rows(up.rows)
        alerts = track.watch.update(up.s, wall, pose, item.frame.index, now)
        segments = self._segments()
        self.cost.add(wall.line.rows_end, time.perf_counter() - t0, len(up.rows))
        state.update_wall(rows)
        state.set_segments(segments)
        xyz, rgb = track.new_points(up.points, up.colours, self.settings.map_voxel)
        if len(xyz):
            state.add_map_points(xyz, rgb)
        for a in alerts:
            state.add_alert(a.as_dict())
            self.echo(f"live: ALERT {a.message()}")

    def _wall_rows(self, rows: np.ndarray) -> list[WallRow]:
        assert self.track is not None
        if not len(rows):
            return []
        geo = self.track.wall.rows_geometry(rows)
        return [WallRow(i=int(i), centre=geo["centre"][n], N=geo["N"][n], B=geo["B"][n], radius=geo["radius"][n],
                        observed=geo["observed"][n], measured=geo["observed"][n], colour=geo["colour"][n])
                for n, i in enumerate(rows.tolist())]

    def _segments(self) -> list[dict]:
        track = self.track
        assert track is not None
        current = track.watch.current
        return [{"index": s["index"], "start_m": s["start_m"], "end_m": s["end_m"], "unseen_share": s["unseen_share"],
                 "state": "current" if s["index"] == current else "passed"} for s in track.wall.segments()]

    def _finish(self, outputs: RunOutputs, summary: dict) -> None:
        status = summary.get("status", "error")
        interrupted = "KeyboardInterrupt" in str(summary.get("error", ""))
        track = self.track
        if track is not None and self.state is not None:
            rows = track.wall.finish()
            self.state.update_wall(self._wall_rows(rows))
            alerts = track.watch.update(None, track.wall, np.eye(4), -1, time.time())
            self.state.set_segments(self._segments())
            for a in alerts:  # judged at the end: no pose to tell the clock by
                d = a.as_dict()
                if d["gap"] is not None:
                    d["gap"]["clock"] = None
                self.state.add_alert(d)
                self.echo(f"live: ALERT {a.message()}")
        record = self.record(summary)
        write_json(Path(outputs.root) / LIVE_JSON, record)
        summary["live"] = {k: record[k] for k in ("frames_delivered", "frames_taken", "frames_dropped",
                                                   "dropped_share", "unseen_share_live", "alerts")}
        if self.state is not None:
            end = "interrupted" if interrupted else "finished" if status in ("ok", "truncated") else "error"
            headline = {"out": str(self.out or ""), "status": status, "unseen_share": summary.get("unseen_share"),
                        "registered_share": summary.get("registered_share"), "frames": summary.get("frames"),
                        "live_unseen_share": record["unseen_share_live"]}
            self.state.finish(end, error=summary.get("error"), summary=headline)

    def record(self, summary: dict) -> dict:
        """live.json's content (shares 0..1, metres, milliseconds)."""
        src = self.source
        delivered = src.delivered if src else 0
        dropped = src.dropped if src else 0
        snap = self.state.snapshot(self.state.version) if self.state is not None else {}
        parts = sorted(self.tracks.items(), key=lambda kv: -kv[1].wall.n_rows)
        wall = parts[0][1].wall if parts else None  # the longest map part's
        return {
            "source": src.describe() if src else None,
            "settings": {k: getattr(self.settings, k) for k in self.settings.__dataclass_fields__},
            "frames_delivered": delivered, "frames_taken": summary.get("frames", self.taken), "frames_dropped": dropped,
            "dropped_share": dropped / delivered if delivered else 0.0,
            "drop_rule": "newest frame wins: a frame still waiting when the next arrives is dropped",
            "delays_ms": snap.get("rates", {}).get("delays"),
            "unseen_wall_update": self.cost.as_list(),
            "unseen_share_live": wall.unseen_share() if wall is not None else None,
            "segments_live": wall.segments() if wall is not None else [],
            "map_parts": [{"part": k, "wall_rows": t.wall.n_rows, "frames": t.wall.frames,
                           "unseen_share_live": t.wall.unseen_share()} for k, t in parts],
            "map_part_switches": self.switches,
            "alerts": [a.as_dict() for _, t in parts for a in t.watch.alerts],
            "unseen_share_run": summary.get("unseen_share"),
            "convention": "the live estimate (of the map part with the longest wall) uses each frame's pose when it "
                          "was placed and its depth points; unseen_share_run is the run's estimate at the end "
                          "(optimised poses, fused mesh, the main map)",
        }

    def close(self, linger: float = 0.0) -> None:
        """Keep the page up ``linger`` seconds (Ctrl-C ends that early), then stop the server."""
        try:
            if self.server is not None and linger > 0:
                self.echo(f"live: the page stays at {self.server.url} for {linger:.0f} s (Ctrl-C ends it)")
                time.sleep(linger)
        except KeyboardInterrupt:
            pass
        finally:
            if self.server is not None:
                self.server.stop()
                self.server = None


def check_port(host: str, port: int) -> None:
    """InputError naming the port when the page could not be served there (before the run starts)."""
    if port == 0:
        return
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as probe:
        probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            probe.bind((host, port))
        except OSError as exc:
            raise InputError(f"--port {port}: the page cannot be served on {host}:{port} ({exc.strerror or exc}); "
                             "choose another port, or 0 for any free one") from None


def run_live(source: str | Path | int, out: str | Path, cfg: SlamConfig, inputs: RunInputs, settings: LiveSettings,
             *, overwrite: bool = False, live: LiveRun | None = None) -> tuple[dict, LiveRun]:
    """Run ``source`` (video, sequence folder, or an OpenCV capture device index) live into the
    run folder ``out``; returns the summary and the :class:`LiveRun` (given, or made here; its
    server stopped after ``settings.linger`` seconds, at once on errors)."""
    check_port(settings.host, settings.port)
    live = live or LiveRun(settings, cfg)
    live.out = Path(out)
    try:
        summary = run_slam(source, out, cfg, inputs, progress=False, overwrite=overwrite, observer=live)
    except BaseException:
        live.close(0.0)
        raise
    live.close(settings.linger)
    return summary, live
