"""Checks a user can read without ground truth: how well a finished run agrees with itself.

After the map is fused, a few registered frames are read again (at most ``checks.frames``, evenly
spread) and compared, inside the tissue area, with what the run made of them:

- ``photometric``: the zero-mean normalised cross-correlation of the frame's luma with the fused
  mesh's colour rendered at the frame's pose, both band-passed (:func:`_band`; specular
  highlights left out): 1 = the map looks like the frame where the frame sees it, a wrong pose or
  a smeared map lowers it; and the share of the tissue area the map covers there
  (``map_coverage``);
- ``map_depth``: the median relative difference between the frame's depth and the map's depth
  rendered at its pose;
- ``keyframe_depth``: for neighbouring keyframes of the main map (consecutive in time), the
  median relative difference between the depth of one, moved into the other with their final
  poses, and the other's own depth (where both see the same surface): the depth and the poses
  must agree for it to be small.

Renders are made at most ``checks.size_px`` pixels on the long side (Open3D ray casting, CPU).
Each value is reported per frame or pair and as a median in summary.json's ``checks``; the
settings part is ``checks``. The jitter of the trajectory (``jitter_ratio``) is in the same
place. None of them needs ground truth; how each moves with the error it stands for (and where it
does not): docs/runtime.md, Checks without ground truth.
"""

from __future__ import annotations

import copy
import time

import cv2
import numpy as np
from open3d.geometry import TriangleMesh

from c3f_slam.camera.intrinsics import PinholeCamera
from c3f_slam.config import SlamConfig
from c3f_slam.evaluation.trajectory import jitter_ratio
from c3f_slam.frames.preprocess import specular_mask
from c3f_slam.geometry import invert_pose, project, transform_points
from c3f_slam.pipeline.backend import SlamMap
from c3f_slam.pipeline.sources import RunSources
from c3f_slam.view.raycast import NO_HIT, MeshScene, pinhole_rays

#: the fewest pixels a comparison needs to be reported (fewer: None)
MIN_PIXELS = 50
#: the photometric comparison is of band-passed luma: blurred by this share of the long side (the
#: fused colours are coarser than the frame: one colour per voxel, averaged over frames) ...
BLUR = 0.015
#: ... less its blur by this share (the scope's light falls off with distance, so the map's colours,
#: fused from many distances, differ from a frame's in their slow shading, not in texture and folds)
LIGHTING = 0.08


def _zncc(a: np.ndarray, b: np.ndarray) -> float | None:
    """Zero-mean normalised cross-correlation of two equal-length vectors (None when either is flat)."""
    a, b = a - a.mean(), b - b.mean()
    den = float(np.sqrt((a * a).sum() * (b * b).sum()))
    return float((a * b).sum() / den) if den > 0 else None


def _band(luma: np.ndarray, side: int) -> np.ndarray:
    """Band-pass luma: blurred by :data:`BLUR` of the long side ``side`` (the map's resolution),
    less its blur by :data:`LIGHTING` (the light's fall-off, which differs from frame to frame)."""
    x = luma.astype(np.float32)
    return cv2.GaussianBlur(x, (0, 0), BLUR * side) - cv2.GaussianBlur(x, (0, 0), LIGHTING * side)


def _rel_diff(d: np.ndarray, ref: np.ndarray) -> float:
    """Median of |d - ref| / ref."""
    return float(np.median(np.abs(d - ref) / ref))


def _small(camera: PinholeCamera, size_px: int) -> PinholeCamera:
    scale = min(1.0, size_px / max(camera.width, camera.height))
    return camera.resize(max(8, round(camera.width * scale)), max(8, round(camera.height * scale)))


def _render(scene: MeshScene, cam: PinholeCamera, T_wc: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(h, w) luma of the mesh's own colours (0..255, unshaded) and its depth (metres, 0 = no hit)."""
    rays = pinhole_rays(cam.K, T_wc, cam.width, cam.height)
    hit = scene.cast(rays)
    colour = scene.shade(rays, hit, background=(0, 0, 0), ambient=1.0)
    ok = hit["primitive_ids"] != NO_HIT
    depth = np.where(ok, hit["t_hit"], 0.0).astype(np.float32)  # ray parameter = z (pinhole_rays)
    return cv2.cvtColor(colour, cv2.COLOR_RGB2GRAY).astype(np.float32), depth


def photometric_agreement(scene: MeshScene, cam: PinholeCamera, T_wc: np.ndarray, rgb: np.ndarray,
                          mask: np.ndarray) -> tuple[float | None, np.ndarray]:
    """The ZNCC of a frame's band-passed luma with the map's rendered at camera-to-world ``T_wc``
    (inside ``mask``, where the map is hit, specular highlights left out; None: too few pixels),
    and the map's depth there ((h, w) metres, 0 = no hit). ``rgb`` (h, w, 3) uint8 of ``cam``'s size."""
    r_luma, r_depth = _render(scene, cam, T_wc)
    side = max(cam.width, cam.height)
    luma, r_luma = _band(cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY), side), _band(r_luma, side)
    matte = mask & (r_depth > 0) & ~specular_mask(rgb, dilation_px=3)
    if matte.sum() < MIN_PIXELS:
        return None, r_depth
    return _zncc(luma[matte].astype(np.float64), r_luma[matte].astype(np.float64)), r_depth


def _frames(sources: RunSources, wanted: set[int]):
    """The stream's frames whose index is in ``wanted`` (read again through a copy of the stream)."""
    stream = copy.copy(sources.stream)
    stream.quality = None  # the frames the run registered passed it; read them as they are
    for frame in stream:
        if frame.index in wanted and frame.usable:
            yield frame
        if frame.index >= max(wanted):
            return


def _keyframe_pairs(slam_map: SlamMap, registered: dict[int, np.ndarray], limit: int) -> list[tuple[int, int]]:
    """Consecutive registered keyframes (frame indices), at most ``limit`` pairs evenly spread."""
    graph = slam_map.keyframe_graph()
    frames = sorted({n.frame for n in graph.nodes if n.frame in registered}) if graph is not None else []
    pairs = list(zip(frames[:-1], frames[1:]))
    if len(pairs) > limit:
        pairs = [pairs[i] for i in np.linspace(0, len(pairs) - 1, limit).round().astype(int)]
    return pairs


def _pair_depth(a: tuple[np.ndarray, np.ndarray], b: tuple[np.ndarray, np.ndarray], K: np.ndarray,
                mask: np.ndarray) -> float | None:
    """Median relative difference of frame a's depth moved into frame b against b's own depth.
    ``a``, ``b``: (depth (h, w) metres, camera-to-world pose)."""
    (da, Ta), (db, Tb) = a, b
    v, u = np.nonzero((da > 0) & mask)
    z = da[v, u].astype(np.float64)
    pts = np.stack([(u - K[0, 2]) / K[0, 0] * z, (v - K[1, 2]) / K[1, 1] * z, z], axis=1)
    uv, zb = project(transform_points(invert_pose(Tb) @ Ta, pts), K)
    px = np.rint(np.where(np.isfinite(uv), uv, -1.0)).astype(np.int64)
    h, w = db.shape
    inside = (zb > 0) & (px[:, 0] >= 0) & (px[:, 0] < w) & (px[:, 1] >= 0) & (px[:, 1] < h)
    ref = np.zeros(len(zb))
    ref[inside] = db[px[inside, 1], px[inside, 0]]
    ok = inside & (ref > 0) & mask[np.clip(px[:, 1], 0, h - 1), np.clip(px[:, 0], 0, w - 1)]
    # where b sees a nearer surface (an occlusion), the two do not see the same point
    ok &= zb < 1.5 * np.where(ref > 0, ref, np.inf)
    return _rel_diff(zb[ok], ref[ok]) if ok.sum() >= MIN_PIXELS else None


def _median(values: list[float | None]) -> float | None:
    v = [x for x in values if x is not None]
    return float(np.median(v)) if v else None


def self_checks(mesh: TriangleMesh | None, slam_map: SlamMap, sources: RunSources, cfg: SlamConfig) -> dict:
    """summary.json's ``checks`` for a finished run (see the module notes)."""
    c = cfg.checks
    index, stamps, poses, reg = slam_map.trajectory()
    jitter = jitter_ratio(poses[reg, :3, 3], stamps[reg], c.jitter_window_s)
    out: dict = {"jitter_ratio": jitter if np.isfinite(jitter) else None}  # None: a path shorter than the window
    if not c.enabled:
        return {"checks": {**out, "status": "off"}}
    t0 = time.perf_counter()
    registered = {int(i): P for i, P, r in zip(index, poses, reg) if r}
    cam = _small(sources.camera, c.size_px)
    size = (cam.width, cam.height)
    mask = cv2.resize(sources.tissue.pixels.astype(np.uint8), size, interpolation=cv2.INTER_NEAREST) > 0
    rows = sorted(registered)
    sampled = [rows[i] for i in np.unique(np.linspace(0, len(rows) - 1, c.frames).round().astype(int))] if rows else []
    pairs = _keyframe_pairs(slam_map, registered, c.frames)
    wanted = set(sampled) | {f for p in pairs for f in p}
    scene = MeshScene.of(mesh) if mesh is not None and len(mesh.triangles) else None
    photometric, coverage, map_depth, depths = {}, {}, {}, {}
    for frame in _frames(sources, wanted) if wanted else ():
        depth = cv2.resize(sources.depth.depth(frame), size, interpolation=cv2.INTER_NEAREST)
        depths[frame.index] = (depth, registered[frame.index])
        if scene is None or frame.index not in sampled:
            continue
        rgb = cv2.resize(frame.rgb, size, interpolation=cv2.INTER_AREA)
        photometric[frame.index], r_depth = photometric_agreement(scene, cam, registered[frame.index], rgb, mask)
        seen = mask & (r_depth > 0)
        coverage[frame.index] = float(seen.sum() / max(1, mask.sum()))
        both = seen & (depth > 0)
        if both.sum() >= MIN_PIXELS:
            map_depth[frame.index] = _rel_diff(depth[both].astype(np.float64), r_depth[both].astype(np.float64))
    keyframe_depth = {f"{a}-{b}": _pair_depth(depths[a], depths[b], cam.K, mask)
                      for a, b in pairs if a in depths and b in depths}
    out.update(
        status="ok" if scene is not None else "no mesh: photometric and map depth not checked",
        frames=len(sampled), keyframe_pairs=len(keyframe_depth),
        photometric_zncc=_median(list(photometric.values())), map_coverage=_median(list(coverage.values())),
        map_depth_rel=_median(list(map_depth.values())), keyframe_depth_rel=_median(list(keyframe_depth.values())),
        per_frame={str(i): {"photometric_zncc": photometric.get(i), "map_coverage": coverage.get(i),
                            "map_depth_rel": map_depth.get(i)} for i in sampled},
        per_keyframe_pair=keyframe_depth, seconds=time.perf_counter() - t0,
    )
    return {"checks": out}
