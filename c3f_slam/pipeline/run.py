"""Run the SLAM runtime on a sequence folder or a video and write its outputs (docs/runtime.md).

:func:`run_slam` opens the run (inputs checked and opened once: :mod:`.sources`), then a
:class:`SlamRun` (a context manager that owns the run's resources: the BLAS thread limit,
the progress bar, the frames fusion re-reads, the back-end) takes one frame at a time
(:meth:`SlamRun.step`): :class:`c3f_slam.frames.stream.FrameStream` reads it and perception
(:mod:`.perception`, a worker thread a few frames ahead of the loop: ``frames.prefetch``) gives,
inside the frames' tissue area (:mod:`c3f_slam.frames.tissue`: the scope's border and overlays left out),
its depth (files, or DepthNet ONNX) and its keypoints, descriptors (SIFT or ContraFeat ONNX)
and 3D points; flagged frames (black, saturated, and those the frame-quality gate finds blurred,
dark, washed out, covered or repeated: ``frames.quality``) are skipped and counted by cause, the back-end
(:class:`~c3f_slam.pipeline.backend.SlamBackend`) places the frame (its
:class:`~c3f_slam.pipeline.frame_step.FrameDecision` is counted), and fusion records the
frame under its fragment. At the end the main map is fused with its final poses, re-reading
its frames through :mod:`c3f_slam.pipeline.fusion_frames` (the sequence's files, or the
on-disk cache of predicted depth, removed at the end), and the components of the map that
could not be joined to it are written beside it (:mod:`c3f_slam.pipeline.components`).
The global stage keeps its keyframes' features in ``OUT/.keyframe_cache`` (removed at the
end, also on errors; ``keyframes.cache=False`` keeps them in RAM). Whatever happens, the
outputs so far (trajectory.txt, summary.json with the error, keyframe graph) are written
atomically before the error is passed on.
"""

from __future__ import annotations

import contextlib
import time
import traceback
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol

import numpy as np
from open3d.geometry import TriangleMesh
from threadpoolctl import threadpool_limits

from c3f_core.errors import InputError
from c3f_slam.config import SlamConfig
from c3f_slam.frames.quality import QUALITY_CAUSES
from c3f_slam.frames.stream import UNREADABLE, FrameStream, StreamFrame
from c3f_slam.fusion.tsdf import FragmentFusion, TSDFVolume, write_mesh
from c3f_slam.io.run_outputs import FrameLog, RunFolder, RunOutputs
from c3f_slam.pipeline.backend import BackendFactory, SlamBackend
from c3f_slam.pipeline.components import (
    ComponentEntry,
    MapComponent,
    component_summary,
    plan_components,
    write_components,
)
from c3f_slam.pipeline.coverage_stage import run_coverage
from c3f_slam.pipeline.frame_step import DecisionCounts, FrameDecision, FrameInput
from c3f_slam.pipeline.frontend import Frontend
from c3f_slam.pipeline.fusion_frames import FusionFrames, fusion_frames
from c3f_slam.pipeline.keyframe_store import CACHE_DIR as KEYFRAME_CACHE_DIR
from c3f_slam.pipeline.odometry import OdometrySlam
from c3f_slam.pipeline.perception import PerceivedFrame, Perception, Prefetcher
from c3f_slam.pipeline.self_checks import self_checks
from c3f_slam.pipeline.slam import FragmentSlam
from c3f_slam.pipeline.sources import RunInputs, RunSources, open_sources
from c3f_slam.pipeline.timings import Timings

SKIP_REASONS = ("black", "saturated", "featureless", "unreadable", *QUALITY_CAUSES)


@dataclass
class FrameCounts:
    """Frames streamed, processed, skipped by reason, and the back-end's decisions on the
    processed ones by kind (summary.json; ``frame_decisions``)."""

    frames: int = 0
    processed: int = 0
    skipped: dict[str, int] = field(default_factory=lambda: dict.fromkeys(SKIP_REASONS, 0))
    decisions: DecisionCounts = field(default_factory=DecisionCounts)

    def as_dict(self) -> dict:
        return {"frames": self.frames, "processed": self.processed,
                **{f"skipped_{k}": v for k, v in self.skipped.items()}, "frame_decisions": self.decisions.as_dict()}


class RunObserver(Protocol):
    """Something that follows a run as it happens (the live view, :mod:`c3f_slam.live`): it may
    replace the frames the run takes, sees each frame's outcome, and ends with the run."""

    def frames(self, stream: FrameStream) -> Iterable[StreamFrame]:
        """The frames the run takes (the stream itself, or paced and thinned as a capture)."""

    def opened(self, run: SlamRun) -> None:
        """The run's sources and back-end are open, its frames are :meth:`frames` (before the first)."""

    def stepped(self, run: SlamRun, item: PerceivedFrame, outcome: str, decision: FrameDecision | None) -> None:
        """A frame was taken: ``outcome`` its skip reason or the back-end's decision kind."""

    def finished(self, outputs: RunOutputs, summary: dict) -> None:
        """The run ended (``summary['status']``), its outputs written, before the folder is
        published; may add files to ``outputs.root``. Never raises."""


def _progress(total: int | None, enabled: bool):
    if not enabled:
        return None
    try:
        from tqdm import tqdm
    except ImportError:  # pragma: no cover
        return None
    return tqdm(total=total, unit="frame", desc="slam", dynamic_ncols=True, mininterval=0.5)


class SlamRun:
    """One run over opened ``sources``: the back-end, the frontend, fusion, and the resources
    they hold (freed by :meth:`close`, also on errors; use it as a context manager)."""

    def __init__(self, cfg: SlamConfig, sources: RunSources, outputs: RunOutputs, timings: Timings,
                 factory: BackendFactory, progress: bool, observer: RunObserver | None = None) -> None:
        self.cfg, self.sources, self.timings, self.outputs = cfg, sources, timings, outputs
        self.observer = observer
        self.counts = FrameCounts()
        self.log = FrameLog(outputs.frame_log)  #: what happened to each frame, written as it happens
        self.components: list[ComponentEntry] | None = None  #: after finish(): the map's components
        self.backend: SlamBackend | None = None
        self.frames: FusionFrames | None = None
        self.fusion: FragmentFusion | None = None
        self.bar = None
        self._blas = threadpool_limits(limits=cfg.blas_threads, user_api="blas") if cfg.blas_threads else None
        try:
            self._open(outputs, factory, progress)
        except BaseException:
            self.close()
            raise

    def _open(self, outputs: RunOutputs, factory: BackendFactory, progress: bool) -> None:
        cfg, sources = self.cfg, self.sources
        cache = outputs.root / KEYFRAME_CACHE_DIR if cfg.keyframes.cache else None
        K = sources.camera.K
        self.backend = backend = factory(cfg, K, sources.describer.metric, self.timings, keyframe_cache=cache)
        tissue = None if sources.tissue.whole_frame else sources.tissue.pixels
        self.frontend = Frontend(K, sources.describer, cfg.frontend, tissue)
        if cfg.fusion.enabled:
            self.frames = fusion_frames(sources.depth, sources.stream.sequence, lambda row: backend.map.log.index[row],
                                        outputs.root)
            self.fusion = FragmentFusion(TSDFVolume(cfg.fusion.tsdf), self.frames.load, self.frames.K)
        self.bar = _progress(len(sources.stream), progress)

    def __enter__(self) -> SlamRun:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def run(self) -> TriangleMesh | None:
        """Every frame of the stream (perceived ahead of the back-end: ``frames.prefetch``),
        then the end of the run; returns the mesh (None without fusion)."""
        t0 = time.perf_counter()
        perceive = Perception(self.sources.depth, self.frontend)
        try:
            fc = self.cfg.frames
            stream = self.sources.stream
            taken = stream
            if self.observer is not None:
                taken = self.observer.frames(stream)
                self.observer.opened(self)
            with Prefetcher(taken, perceive, fc.prefetch, fc.perception_workers) as frames:
                for item in frames:
                    self.step(item)
                self.timings.add("wait", frames.wait_seconds)
            return self.finish()
        finally:
            self.timings.wall_seconds = time.perf_counter() - t0

    def step(self, item: PerceivedFrame) -> None:
        """One perceived frame: skip it, or the back-end and fusion."""
        frame = item.frame
        self.counts.frames += 1
        for stage, seconds in item.seconds.items():
            self.timings.add(stage, seconds)
        if self.bar is not None:
            self.bar.update(1)
        if not frame.usable:
            self._skip(item, frame.status)
            if frame.status == UNREADABLE:
                self._check_bad_frames(frame)
            return
        feat = item.features
        assert feat is not None and item.depth is not None
        if int(np.isfinite(feat.points).all(axis=1).sum()) < self.cfg.match_filter.min_matches:
            self._skip(item, "featureless")
            return
        self.counts.processed += 1
        decision = self.backend.add(FrameInput(feat, item.depth, frame.rgb))
        self.counts.decisions.add(decision)
        self.log.write(frame.index, frame.timestamp, decision.kind)
        if self.fusion is not None and decision.fragment >= 0:
            with self.timings.stage("fusion"):
                self._fuse(decision.fragment, item)
        if self.bar is not None:
            self.bar.set_postfix(kf=self.backend.map.n_keyframes(), refresh=False)
        if self.observer is not None:
            self.observer.stepped(self, item, decision.kind, decision)

    def _check_bad_frames(self, frame: StreamFrame) -> None:
        """InputError once more frames were unreadable than ``--max-bad-frames`` allows."""
        n, limit = self.counts.skipped[UNREADABLE], self.sources.max_bad_frames
        if n > limit:
            raise InputError(f"{frame.error} ({n} unreadable frames, more than --max-bad-frames {limit})")

    def _skip(self, item: PerceivedFrame, reason: str) -> None:
        frame = item.frame
        self.counts.skipped[reason] += 1
        self.log.write(frame.index, frame.timestamp, reason)
        self.backend.skip(frame.index, frame.timestamp)
        if self.observer is not None:
            self.observer.stepped(self, item, reason, None)

    def _fuse(self, fid: int, item: PerceivedFrame) -> None:
        """Record the frame (log row) under its fragment for the fusion at the end."""
        assert self.fusion is not None and self.frames is not None
        row = len(self.backend.map.log) - 1
        self.frames.record(row, item.frame, item.prediction)
        self.fusion.add_frame(fid, row)

    def finish(self) -> TriangleMesh | None:
        """End of the stream: the back-end's final optimisation, the components beside the
        main map written (:mod:`.components`), and the mesh of the main map."""
        self.backend.finish()
        slam_map = self.backend.map
        self.components = plan_components(slam_map.components(), self.cfg.components, self.outputs)
        with self.timings.stage("fusion"):
            fuse = self._fuse_component if self.fusion is not None else None
            write_components(self.components, np.asarray(slam_map.log.stamp), fuse)
            if self.fusion is None:
                return None
            return self.fusion.finalize(slam_map.pose_of_log, slam_map.main_fragments())

    def _fuse_component(self, comp: MapComponent) -> TriangleMesh:
        """The mesh of one component (its frames re-fused with their final poses)."""
        assert self.fusion is not None
        return self.fusion.finalize(comp.pose_of, comp.fragments)

    def close(self) -> None:
        """Free the resources (BLAS limit, progress bar, fusion's frame cache, the back-end's
        keyframe cache); the back-end's trajectory and stats stay readable."""
        self.log.close()
        if self._blas is not None:
            self._blas.restore_original_limits()
            self._blas = None
        if self.bar is not None:
            self.bar.close()
            self.bar = None
        if self.frames is not None:
            self.frames.close()
            self.frames = None
        if self.backend is not None:
            self.backend.close()


def run_slam(
    sequence: str | Path,
    out: str | Path,
    cfg: SlamConfig | None = None,
    inputs: RunInputs | None = None,
    *,
    progress: bool = True, slam_factory: BackendFactory | None = None, overwrite: bool = False,
    observer: RunObserver | None = None,
) -> dict:
    """Run on ``sequence`` (folder, or video file with model depth) and write the outputs into
    the run folder ``out``; returns the summary. ``cfg``: the settings tree (default the colon
    preset; which frames are read: ``cfg.frames``); ``inputs``: descriptors, depth and camera
    choices (:class:`RunInputs`, default SIFT and depth files); ``overwrite``: replace a
    complete earlier run in ``out`` (:class:`RunFolder`); ``slam_factory`` may replace the
    back-end (tests); ``observer`` follows the run (:class:`RunObserver`: the live view). The
    run is built beside ``out`` and moved into place when it ends, also on errors (summary.json
    says ``error`` and how far it got). InputError on bad input, including
    a run in which no frame could be registered (after writing its outputs)."""
    cfg = cfg or SlamConfig()
    inputs = inputs or RunInputs()
    folder = RunFolder(out, overwrite)
    outputs = RunOutputs(folder.claim())
    summary: dict = {
        "sequence": str(sequence), "mode": cfg.mode, "descriptors": inputs.descriptors,
        "depth_source": inputs.depth_source, "preset": cfg.preset, "stride": cfg.frames.stride,
        "max_frames": cfg.frames.max_frames, "status": "running", "config": cfg.as_dict(),
    }
    timings, run, t_start = Timings(), None, time.perf_counter()
    try:
        inputs = inputs.resolved()
        summary.update(descriptors=inputs.descriptors, depth_source=inputs.depth_source)
        sources = open_sources(sequence, inputs, stride=cfg.frames.stride, max_frames=cfg.frames.max_frames,
                               tissue=cfg.tissue,
                               quality=cfg.frames.quality)
        summary.update(sources.summary())
        sources.tissue.write_png(outputs.tissue_mask)
        cfg = cfg.for_frame_size(sources.camera.width, sources.camera.height).for_depth_source(inputs.depth_source)
        summary["config"] = cfg.as_dict()  # with the thresholds derived from the frame size and depth source
        factory = slam_factory or (OdometrySlam if cfg.mode == "odometry" else FragmentSlam)
        with SlamRun(cfg, sources, outputs, timings, factory, progress, observer=observer) as run:
            mesh = run.run()
        summary.update(_write_main_mesh(outputs, mesh))
        summary.update(run_coverage(outputs, mesh, run.backend.map, sources, cfg))
        summary.update(self_checks(mesh, run.backend.map, sources, cfg))
        summary["status"] = "ok"
    except BaseException as exc:  # write what we have, then pass the error on
        _record_error(summary, exc)
        write_run_outputs(outputs, run, summary, t_start)
        if observer is not None:
            observer.finished(outputs, summary)
            outputs.write_summary(summary)
        with contextlib.suppress(OSError):  # keep the original error visible; bad input never
            _keep_or_publish(folder, exc)   # replaces a complete earlier run (--overwrite)
        raise
    write_run_outputs(outputs, run, summary, t_start)
    failed = _truncated(summary, sources.stream) or _no_frame_registered(summary, sequence)
    if failed:
        outputs.write_summary(summary)
    if observer is not None:
        observer.finished(outputs, summary)
        outputs.write_summary(summary)
    folder.publish()
    if failed:
        raise InputError(summary["error"])
    return summary


def _write_main_mesh(outputs: RunOutputs, mesh: TriangleMesh | None) -> dict:
    """Write the main map's mesh (unless empty); summary.json's ``mesh_triangles`` (nothing without fusion)."""
    if mesh is None:
        return {}
    if len(mesh.triangles):
        write_mesh(mesh, outputs.mesh)
    return {"mesh_triangles": int(len(mesh.triangles))}


def _record_error(summary: dict, exc: BaseException) -> None:
    """Mark the summary with the error being handled (a traceback unless bad input or an interrupt)."""
    summary["status"] = "error"
    summary["error"] = f"{type(exc).__name__}: {exc}" if not isinstance(exc, InputError) else str(exc)
    if not isinstance(exc, (InputError, KeyboardInterrupt)):
        summary["traceback"] = traceback.format_exc(limit=8)


def _keep_or_publish(folder: RunFolder, exc: BaseException) -> None:
    """After an error: publish the partial run, unless the error is bad input (InputError) and
    the folder holds a complete earlier run, which is then kept as it was."""
    if isinstance(exc, InputError) and folder.holds_complete_run():
        folder.discard()
    else:
        folder.publish()


def _truncated(summary: dict, stream: FrameStream) -> bool:
    """Mark the summary when the video ended before its declared frame count (status
    ``truncated``: the outputs cover the frames read)."""
    if stream.truncation is None:
        return False
    summary["status"] = "truncated"
    summary["frames_declared"] = stream.truncation.declared
    summary["error"] = stream.truncation.message(stream.source) + "; the run of the frames before it is written"
    return True


def _no_frame_registered(summary: dict, sequence: str | Path) -> bool:
    """Mark the summary as an error when no frame could be registered."""
    if summary.get("registered_frames", 0):
        return False
    summary["status"] = "error"
    summary["error"] = (f"{sequence}: no frame could be registered ({summary['frames']} frames, "
                        f"{summary['skipped_black']} black, {summary['skipped_saturated']} saturated, "
                        f"{summary['skipped_featureless']} featureless)")
    return True


def write_run_outputs(outputs: RunOutputs, run: SlamRun | None, summary: dict, t_start: float) -> None:
    """Trajectory, keyframe graph and summary (each atomically); never raises on top of an error."""
    counts = run.counts if run is not None else FrameCounts()
    summary.update(counts.as_dict())
    summary["wall_seconds"] = time.perf_counter() - t_start
    summary["timings"] = run.timings.as_dict(counts.frames) if run is not None else Timings().as_dict(0)
    try:
        if run is not None and run.backend is not None:
            backend, slam_map = run.backend, run.backend.map
            _, stamps, poses, reg = slam_map.trajectory()
            n = outputs.write_trajectory(stamps, poses, reg)
            summary["registered_frames"] = n
            summary["registered_share"] = n / counts.frames if counts.frames else 0.0
            summary["registered_share_of_usable"] = n / counts.processed if counts.processed else 0.0
            summary.update(backend.stats())
            if run.components is not None:
                summary["components"] = component_summary(run.components, np.asarray(slam_map.log.index), outputs)
            graph = slam_map.keyframe_graph()
            if graph is not None:
                outputs.write_graph(graph)
    except Exception as exc:  # pragma: no cover - keep the original error visible
        summary["output_error"] = f"{type(exc).__name__}: {exc}"
    outputs.write_summary(summary)
