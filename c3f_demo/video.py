"""The demo on a user's own video (``python -m c3f_demo --video FILE``): the stages it adds to the
demo's and the numbers its report shows, none of which needs ground truth.

Stages: ``ingest`` (the video's frames as a sequence folder, ``python -m datamodules.ingest``), then
the demo's own ``train_depth`` / ``ttt_depth`` / ``train_features`` / ``export`` / ``slam`` on that
folder, ``view`` (``python -m c3f_slam view`` of the run the report shows) and the report
(:class:`c3f_demo.report_stage.VideoReport`). Lengths in metres, times in seconds.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import asdict
from pathlib import Path

from c3f_core.errors import InputError
from c3f_demo.config import DemoConfig, VideoConfig
from c3f_demo.context import DemoContext
from c3f_demo.stages import Stage
from c3f_slam.io.run_outputs import FrameLog, RunOutputs
from datamodules.ingest import RECORD, open_video

VIEW_FILES = ("view.html", "rerender.mp4", "flythrough.mp4")


def check_video(v: VideoConfig) -> None:
    """Bad input before any stage runs (one line each): the video missing or not decoding, no
    intrinsics (no --camera, no --fov, no camera.json beside the video: ``v.camera`` is then None),
    a camera that does not fit it."""
    if v.camera is None and v.fov is None and Path(v.path).is_file():
        raise InputError(f"--video {v.path}: no intrinsics: pass --camera camera.json (`python -m c3f_slam "
                         "calibrate` makes one), or guess them with --fov DEG, or put a camera.json beside the video")
    open_video(v.path, v.camera, v.fov)


def _file_signature(path: str | None, content: bool = False) -> dict | None:
    """Size and modification time of a file (``content``: its SHA-256 instead), for a stage's key."""
    if path is None:
        return None
    p = Path(path)
    if content:
        return {"sha256": hashlib.sha256(p.read_bytes()).hexdigest()}
    st = p.stat()
    return {"bytes": st.st_size, "mtime_ns": st.st_mtime_ns}


def camera_args(v: VideoConfig) -> list[str]:
    """The ``--camera`` / ``--fov`` options of the video's intrinsics (none: camera.json beside it)."""
    if v.fov is not None:
        return ["--fov", repr(v.fov)]
    return ["--camera", v.camera] if v.camera else []


class Ingest(Stage):
    """The video's frames as the sequence folder every later stage reads (``DIR/data/video``)."""

    name = "ingest"

    def settings(self, cfg: DemoConfig) -> dict:
        v = cfg.video
        return {**asdict(v), "video_file": _file_signature(v.path), "camera_file": _file_signature(v.camera, True)}

    def outputs(self, ctx):
        return [ctx.test_seq, *ctx.test_seq.parent.glob(f".{ctx.test_seq.name}.partial-*"), ctx.log(self.name)]

    def estimate_s(self, cfg):
        return 3.0 + 0.01 * cfg.video.max_frames

    def probe(self, ctx):
        def done() -> float | None:
            parts = list(ctx.test_seq.parent.glob(f".{ctx.test_seq.name}.partial-*/rgb"))
            return len(list(parts[0].glob("*.png"))) / ctx.cfg.video.max_frames if parts else None
        return done

    def run(self, ctx, done=None):
        v = ctx.cfg.video
        ctx.run(self.name, ["-m", "datamodules.ingest", v.path, "--out", str(ctx.test_seq), *camera_args(v),
                            "--max-fps", repr(v.max_fps), "--max-frames", str(v.max_frames),
                            "--max-side", str(v.max_side)])
        return json.loads((ctx.test_seq / RECORD).read_text())


class View(Stage):
    """``python -m c3f_slam view`` of the run the report shows, as the demo's report does: the
    paper's configuration, else the first that worked (view.html, rerender.mp4, flythrough.mp4 in
    its run folder). A view that fails is noted, not fatal."""

    name = "view"
    upstream = ("slam",)

    def outputs(self, ctx):
        return [*(ctx.slam_dir(n) / f for n in ctx.slam_runs for f in VIEW_FILES),
                *(ctx.log(f"{self.name}_{n}") for n in ctx.slam_runs)]

    def estimate_s(self, cfg):
        return 8.0 + (cfg.sequence_frames + 240) * 0.045  # 45 ms per rendered frame, 240 fly-through frames

    def run(self, ctx, done=None):
        runs = (done or {}).get("notes", {}).get("slam", {}).get("runs", {})
        ok = [n for n in ctx.slam_runs if runs.get(n, {}).get("status") == "ok"]
        failed = ctx.run_many(self.name, {n: ["-m", "c3f_slam", "view", str(ctx.slam_dir(n)), "--no-open", "--quiet"]
                                          for n in ok[:1]})
        return {"views": {n: None if exc is None else str(exc) for n, exc in failed.items()}}


def jitter(run: Path) -> dict:
    """The trajectory's jitter ratio (:func:`c3f_slam.evaluation.trajectory.jitter_ratio`: path length
    over the length of its 1-s moving average; 1 = smooth) and path length (metres, the run's own
    scale); the run's timestamps are the frames' times in the video (the sequence's times.txt)."""
    from c3f_slam.evaluation.trajectory import jitter_ratio, path_length
    from c3f_slam.io import read_tum

    stamps, poses = read_tum(run / "trajectory.txt")
    positions = poses[:, :3, 3]
    return {"jitter_ratio": jitter_ratio(positions, stamps), "path_length_m": path_length(positions),
            "seconds": float(stamps.max() - stamps.min()) if len(stamps) else 0.0}


def frame_log(run: Path) -> list[str] | None:
    """Per frame of the run's ``frame_log.csv`` (:class:`~c3f_slam.io.run_outputs.FrameLog`), in
    the order of the frames, its outcome; None without the file."""
    path = RunOutputs(run).frame_log
    if not path.is_file():
        return None
    return [outcome for _, outcome in sorted(FrameLog.read(path).items())]


def frame_counts(summary: dict) -> dict[str, int]:
    """The run's frames split by what became of them: registered (main map), processed but not in
    the main map, and skipped per cause (summary.json ``skipped_*``); zero counts left out."""
    registered = int(summary.get("registered_frames", 0))
    counts = {"registered": registered, "not registered": int(summary.get("processed", 0)) - registered}
    counts |= {k.removeprefix("skipped_"): int(v) for k, v in summary.items() if k.startswith("skipped_")}
    return {k: v for k, v in counts.items() if v > 0}


def run_metrics(ctx: DemoContext, name: str, note: dict) -> dict:
    """One run's numbers for the report (``metrics/slam.json``): registered share, frames per cause,
    the back-end's decisions, tissue mask, unseen share, jitter ratio; a failed run keeps its error."""
    res = {"title": note.get("title", name), "status": note.get("status", "failed")}
    if note.get("error"):
        res["error"] = note["error"]
    summary_path = ctx.slam_dir(name) / "summary.json"
    if not summary_path.is_file():
        return res
    s = json.loads(summary_path.read_text())
    res |= {k: s.get(k) for k in ("frames", "processed", "registered_frames", "registered_share",
                                  "registered_share_of_usable", "frame_decisions", "tissue_mask", "unseen_share",
                                  "camera_source", "wall_seconds")}
    res["skipped"] = {k.removeprefix("skipped_"): v for k, v in s.items() if k.startswith("skipped_")}
    res["frame_counts"] = frame_counts(s)
    if res["status"] == "ok":
        try:
            res |= jitter(ctx.slam_dir(name))
        except InputError as exc:
            res["jitter_error"] = str(exc)
    return res


__all__ = ["Ingest", "View", "check_video", "frame_counts", "frame_log", "jitter", "run_metrics"]
