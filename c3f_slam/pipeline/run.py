"""Run the SLAM runtime on a sequence folder or a video and write its outputs (SPEC §4, §5.2).

One frame at a time: :class:`c3f_slam.stream.FrameStream` reads it (a sequence folder, or a
video in model-depth mode), flagged frames (black / saturated) are skipped and counted, the
depth provider gives its depth (files, or DepthNet ONNX), the frontend keeps only keypoints,
descriptors (SIFT or ContraFeat ONNX) and 3D points, fusion re-reads settled fragments through
:mod:`c3f_slam.pipeline.fusion_frames` (the sequence's files, or the on-disk cache of
predicted depth, removed at the end); the global stage keeps its keyframes' descriptors and
3D points in ``OUT/.keyframe_cache`` (:mod:`c3f_slam.pipeline.keyframe_store`, removed at the
end, also on errors; ``SlamConfig.keyframe_cache=False`` keeps them in RAM). Whatever
happens, the outputs so far (trajectory.txt, summary.json with the error, keyframe graph) are
written atomically before the error is passed on.
"""

from __future__ import annotations

import time
import traceback
from pathlib import Path

import numpy as np
from threadpoolctl import threadpool_limits

from c3f_slam.camera import PinholeCamera
from c3f_slam.errors import InputError
from c3f_slam.fusion import FragmentFusion, TSDFVolume, write_mesh
from c3f_slam.models import DepthModel, DescriptorModel
from c3f_slam.outputs import KeyframeGraph, RunOutputs
from c3f_slam.pipeline.config import SlamConfig
from c3f_slam.pipeline.frontend import (
    ContraFeatDescriptors,
    DepthProvider,
    DescriptorProvider,
    FileDepth,
    Frontend,
    ModelDepth,
    SiftDescriptors,
)
from c3f_slam.pipeline.fusion_frames import fusion_frames
from c3f_slam.pipeline.keyframe_store import CACHE_DIR as KEYFRAME_CACHE_DIR
from c3f_slam.pipeline.slam import FragmentSlam, OdometrySlam, Timings
from c3f_slam.stream import FrameStream

DESCRIPTORS = ("sift", "contrafeat")
DEPTH_SOURCES = ("files", "model")


def resolve_sources(
    descriptors: str | None, depth_source: str | None, depth_model: str | None, feature_model: str | None
) -> tuple[str, str]:
    """(descriptors, depth source) of the command-line choices; None follows the models given
    (``--depth-model`` alone means model depth, ``--feature-model`` alone ContraFeat).
    InputError for unknown values, a model choice without its file, or a file left unused."""
    descriptors = descriptors or ("contrafeat" if feature_model else "sift")
    depth_source = depth_source or ("model" if depth_model else "files")
    if descriptors not in DESCRIPTORS:
        raise InputError(f"--descriptors must be one of {DESCRIPTORS}, got {descriptors!r}")
    if depth_source not in DEPTH_SOURCES:
        raise InputError(f"--depth-source must be one of {DEPTH_SOURCES}, got {depth_source!r}")
    if descriptors == "contrafeat" and not feature_model:
        raise InputError("--descriptors contrafeat needs --feature-model FILE.onnx (a ContraFeat export)")
    if descriptors != "contrafeat" and feature_model:
        raise InputError(f"--feature-model is used with --descriptors contrafeat, not {descriptors}")
    if depth_source == "model" and not depth_model:
        raise InputError("--depth-source model needs --depth-model FILE.onnx (a DepthNet export)")
    if depth_source != "model" and depth_model:
        raise InputError(f"--depth-model is used with --depth-source model, not {depth_source}")
    return descriptors, depth_source


def make_providers(
    descriptors: str | None = "sift", depth_source: str | None = "files", depth_model: str | None = None,
    feature_model: str | None = None, camera: PinholeCamera | None = None, threads: int = 2,
    depth_scale: float | None = None,
) -> tuple[DescriptorProvider, DepthProvider]:
    """The descriptor and depth providers for the command-line choices (see
    :func:`resolve_sources`); model providers load their ONNX file (onnxruntime, ``threads``
    intra-op threads) and are bound to ``camera``, the frames' intrinsics; ``depth_scale``
    multiplies model depth (:class:`ModelDepth`). InputError otherwise."""
    descriptors, depth_source = resolve_sources(descriptors, depth_source, depth_model, feature_model)
    if camera is None and (descriptors == "contrafeat" or depth_source == "model"):
        raise ValueError("model providers need the frames' camera")
    desc: DescriptorProvider = SiftDescriptors()
    depth: DepthProvider = FileDepth()
    if descriptors == "contrafeat":
        desc = ContraFeatDescriptors(DescriptorModel(feature_model, threads, "--feature-model"), camera)
    if depth_source == "model":
        depth = ModelDepth(DepthModel(depth_model, threads, "--depth-model"), camera, depth_scale)
    return desc, depth


def _progress(total: int | None, enabled: bool):
    if not enabled:
        return None
    try:
        from tqdm import tqdm
    except ImportError:  # pragma: no cover
        return None
    return tqdm(total=total, unit="frame", desc="slam", dynamic_ncols=True, mininterval=0.5)


def run_slam(
    sequence: str | Path,
    out: str | Path,
    cfg: SlamConfig | None = None,
    descriptors: str | None = None,
    depth_source: str | None = None,
    depth_model: str | None = None,
    feature_model: str | None = None,
    max_frames: int | None = None,
    stride: int = 1,
    progress: bool = True,
    slam_factory=None,
    camera: str | Path | PinholeCamera | None = None,
    threads: int = 2,
    depth_scale: float | None = None,
) -> dict:
    """Run on ``sequence`` (folder, or video file with model depth) and write the outputs into
    ``out``; returns the summary.

    ``descriptors`` / ``depth_source`` None follow the models given (:func:`resolve_sources`);
    ``camera``: intrinsics of a video (default camera.json beside it); ``threads``:
    onnxruntime intra-op threads; ``depth_scale``: factor on model depth (:class:`ModelDepth`;
    only with model depth; None: the model's recorded ``metric_scale``, else 1). Raises InputError (after writing summary.json with the
    error) on bad input, including a run in which no frame could be registered.
    ``slam_factory(cfg, K, metric, timings, keyframe_cache=folder or None)`` may replace the
    back-end (tests).
    """
    cfg = cfg or SlamConfig()
    outputs = RunOutputs(out)
    summary: dict = {
        "sequence": str(sequence), "mode": cfg.mode, "descriptors": descriptors, "depth_source": depth_source,
        "preset": cfg.preset, "stride": stride, "max_frames": max_frames, "status": "running",
        "config": cfg.as_dict(),
    }
    timings = Timings()
    slam = None
    frames = None
    counts = {"frames": 0, "processed": 0, "skipped_black": 0, "skipped_saturated": 0, "skipped_featureless": 0}
    t_start = time.perf_counter()
    bar = None
    blas = None
    try:
        if cfg.blas_threads is not None:
            blas = threadpool_limits(limits=cfg.blas_threads, user_api="blas")
        descriptors, depth_source = resolve_sources(descriptors, depth_source, depth_model, feature_model)
        summary.update(descriptors=descriptors, depth_source=depth_source)
        stream = FrameStream(sequence, camera=camera, use_depth=depth_source == "files", step=stride,
                             max_frames=max_frames)
        if camera is not None and stream.sequence is not None:
            raise InputError(f"{sequence}: --camera is for videos; a sequence folder uses its camera.json")
        if depth_source == "files":
            if stream.sequence is None:
                raise InputError(f"{sequence}: --depth-source files needs a sequence folder, not a video")
            if not stream.sequence.has_depth:
                raise InputError(f"{sequence}: --depth-source files but the sequence has no depth/ folder")
        cam = stream.camera
        K = cam.K
        summary["camera"] = cam.to_dict()
        if depth_scale is not None and depth_source != "model":
            raise InputError("--depth-scale applies to model depth (--depth-model) only")
        desc, depth_src = make_providers(descriptors, depth_source, depth_model, feature_model, cam, threads,
                                         depth_scale)
        if isinstance(depth_src, ModelDepth):
            summary["depth_scale"] = {"factor": depth_src.scale, "source": depth_src.scale_source}
        summary["models"] = {
            name: {"file": str(p.model.onnx.path), "model": p.model.metadata.describe()}
            for name, p in (("descriptors", desc), ("depth", depth_src)) if hasattr(p, "model")
        }
        front = Frontend(K, desc, cfg.max_keypoints, cfg.sift_contrast_threshold, cfg.mask_specular,
                         cfg.specular_dilation_px)
        factory = slam_factory or (OdometrySlam if cfg.mode == "odometry" else FragmentSlam)
        cache = outputs.root / KEYFRAME_CACHE_DIR if cfg.keyframe_cache else None
        slam = factory(cfg, K, desc.metric, timings, keyframe_cache=cache)

        def pose_of(row: int):
            return slam.pose_of_log(row)

        fusion = None
        if cfg.fuse:
            frames = fusion_frames(depth_src, stream.sequence, lambda row: slam.log.index[row], outputs.root)
            fusion = FragmentFusion(TSDFVolume(cfg.tsdf), frames.load, frames.K, cfg.eps_f_na, cfg.eps_cf_d)
        bar = _progress(len(stream), progress)
        t0 = time.perf_counter()
        for frame in stream:
            t0 = timings.add("io", t0)
            counts["frames"] += 1
            if bar is not None:
                bar.update(1)
            if not frame.usable:
                counts[f"skipped_{frame.status}"] += 1
                slam.skip(frame.index, frame.timestamp)
                t0 = time.perf_counter()
                continue
            depth = depth_src.depth(frame)
            t0 = timings.add("depth", t0)
            kp = front.keypoints(frame.rgb)
            feat = front.describe(frame, kp, depth)
            t0 = timings.add("keypoints", t0)
            if int(np.isfinite(feat.points).all(axis=1).sum()) < cfg.match_filter.min_matches:
                counts["skipped_featureless"] += 1
                slam.skip(frame.index, frame.timestamp)
                t0 = time.perf_counter()
                continue
            counts["processed"] += 1
            fid, _ = slam.add(feat, depth)
            row = len(slam.log) - 1
            t0 = time.perf_counter()
            if fusion is not None and fid >= 0:
                frames.record(row, frame)
                fusion.add_frame(fid, row)
                T = slam.current_pose()
                if T is not None:
                    fusion.step(row, T, pose_of, eligible=slam.in_main)
            t0 = timings.add("fusion", t0)
            if bar is not None:
                bar.set_postfix(kf=len(getattr(slam, "keyframes", [])), refresh=False)
        slam.finish()
        if fusion is not None:
            t0 = time.perf_counter()
            mesh = fusion.finalize(pose_of, slam.main_fragments())
            if len(mesh.triangles):
                write_mesh(mesh, outputs.mesh)
            summary["mesh_triangles"] = int(len(mesh.triangles))
            timings.add("fusion", t0)
        summary["status"] = "ok"
    except BaseException as exc:  # write what we have, then pass the error on
        summary["status"] = "error"
        summary["error"] = f"{type(exc).__name__}: {exc}" if not isinstance(exc, InputError) else str(exc)
        if not isinstance(exc, (InputError, KeyboardInterrupt)):
            summary["traceback"] = traceback.format_exc(limit=8)
        _write(outputs, slam, summary, counts, timings, t_start)
        raise
    finally:
        if blas is not None:
            blas.restore_original_limits()
        if bar is not None:
            bar.close()
        if frames is not None:
            frames.close()
        if slam is not None:
            slam.close()  # removes OUT/.keyframe_cache
    _write(outputs, slam, summary, counts, timings, t_start)
    if summary.get("registered_frames", 0) == 0:
        msg = (f"{sequence}: no frame could be registered ({counts['frames']} frames, "
               f"{counts['skipped_black']} black, {counts['skipped_saturated']} saturated, "
               f"{counts['skipped_featureless']} featureless)")
        summary["status"], summary["error"] = "error", msg
        outputs.write_summary(summary)
        raise InputError(msg)
    return summary


def _write(outputs: RunOutputs, slam, summary: dict, counts: dict, timings: Timings, t_start: float) -> None:
    """Trajectory, keyframe graph and summary (each atomically); never raises on top of an error."""
    summary.update(counts)
    summary["wall_seconds"] = time.perf_counter() - t_start
    summary["timings"] = timings.as_dict(counts["frames"])
    try:
        if slam is not None:
            _, stamps, poses, reg = slam.trajectory()
            n = outputs.write_trajectory(stamps, poses, reg)
            usable = counts["processed"]
            summary["registered_frames"] = n
            summary["registered_share"] = n / counts["frames"] if counts["frames"] else 0.0
            summary["registered_share_of_usable"] = n / usable if usable else 0.0
            summary.update(slam.stats())
            if isinstance(slam, FragmentSlam) and slam.graph.n_nodes:
                pg = slam.graph
                graph = KeyframeGraph.from_posegraph(
                    pg, slam.keyframes.frame_indices.tolist(), slam.keyframes.timestamps.tolist(),
                    lone={k for k in range(pg.n_nodes) if not pg.in_main(k)},
                    fragments=slam.node_fragment.tolist(),
                )
                outputs.write_graph(graph)
    except Exception as exc:  # pragma: no cover - keep the original error visible
        summary["output_error"] = f"{type(exc).__name__}: {exc}"
    outputs.write_summary(summary)
