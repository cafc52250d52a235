"""Generate a whole sequence: build the colon, plan the path, render, write the layout.

Output (SPEC §5.2, via :class:`c3f_slam.io.SequenceWriter`)::

    OUT/
      rgb/NNNNNN.png      uint8 RGB
      depth/NNNNNN.png    uint16, camera.depth_scale units per metre (exact ray-cast depth)
      camera.json         intrinsics (pinhole, no distortion)
      poses.txt           TUM, camera-to-world, metres, timestamps = index / fps
      mesh.ply            the ground-truth mesh the depth was ray cast against
      params.json         seed and every parameter (SimParams.from_dict reads it back)
      frames.csv          per frame: time, arc length, event label (the event's frames and
                          its ramps in and out), wall distance

The sequence is written into a hidden sibling folder and renamed to OUT at the end, so an
interrupted run never leaves a half sequence under OUT; an existing non-empty OUT is only
replaced with ``overwrite=True``. Parameters are validated before anything is written.
"""

from __future__ import annotations

import csv
import json
import shutil
from collections import deque
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterator

import numpy as np
import open3d as o3d

from c3f_slam.camera import PinholeCamera
from c3f_slam.io import SequenceWriter
from c3f_slam.io.atomic import move_into_place, staging_dir
from datamodules.synthetic import noise
from datamodules.synthetic.camera_path import CameraPath, plan_path
from datamodules.synthetic.colon import Colon, build_colon
from datamodules.synthetic.params import LAYOUTS, PAPER_COMMON, PAPER_TABLE, SimParams, check_layout, check_output
from datamodules.synthetic.render import Renderer, make_scene
from datamodules.synthetic.texture import TextureAtlas, build_atlas

FORMAT_VERSION = 1
__all__ = ["LAYOUTS", "SimScene", "build_scene", "check_output", "generate_sequence", "read_event_labels",
           "render_frames"]


@dataclass
class SimScene:
    """Everything needed to render the frames of one parameter set."""

    params: SimParams
    colon: Colon
    atlas: TextureAtlas
    raycaster: o3d.t.geometry.RaycastingScene
    path: CameraPath
    camera: PinholeCamera
    renderer: Renderer


def make_camera(params: SimParams) -> PinholeCamera:
    c = params.camera
    return PinholeCamera.from_fov(c.width, c.height, c.fov, depth_scale=c.depth_scale)


def build_scene(params: SimParams) -> SimScene:
    """Validate ``params`` and build colon, texture and path (deterministic in the seed)."""
    params.validate()
    seed = params.seed
    colon = build_colon(params.colon, noise.stream(seed, noise.GEOMETRY))
    raycaster = make_scene(colon)
    path = plan_path(colon, params.path, noise.stream(seed, noise.PATH), raycaster)
    atlas = build_atlas(colon, params.appearance, noise.stream(seed, noise.TEXTURE))
    camera = make_camera(params)
    renderer = Renderer(colon, atlas, camera, params.appearance, scene=raycaster)
    return SimScene(params, colon, atlas, raycaster, path, camera, renderer)


def _blur_poses(scene: SimScene, i: int) -> list[np.ndarray]:
    """Poses inside the shutter interval before frame i (motion blur), none when off."""
    a = scene.params.appearance
    if a.motion_blur <= 0 or i == 0:
        return []
    path = scene.path
    T0, T1 = path.poses[i - 1], path.poses[i]
    step = np.linalg.norm(T1[:3, 3] - T0[:3, 3])
    cos = np.clip((np.trace(T0[:3, :3].T @ T1[:3, :3]) - 1) / 2, -1, 1)
    # rough motion in pixels: translation over ~2 cm of depth plus rotation
    px = a.motion_blur * scene.camera.fx * (step / 0.02 + float(np.arccos(cos)))
    k = int(min(8, np.ceil(px / 1.5)))
    if k <= 1:
        return []
    return [path.pose_at(i - a.motion_blur * j / k) for j in range(1, k)]


def render_frames(scene: SimScene,
                  renderer: Renderer | None = None) -> Iterator[tuple[int, np.ndarray, np.ndarray]]:
    """Yield (index, rgb uint8 (H, W, 3), depth float32 metres (H, W)) for every frame.

    ``renderer``: another camera's renderer of the same scene (default ``scene.renderer``).
    The rays of frame i+1 are cast in a worker thread (Open3D releases the GIL) while
    frame i is shaded; the result does not depend on this overlap.
    """
    seed = scene.params.seed
    r = scene.renderer if renderer is None else renderer
    poses = scene.path.poses
    with ThreadPoolExecutor(max_workers=1) as pool:
        nxt = pool.submit(r.trace, poses[0]) if len(poses) else None
        for i, T in enumerate(poses):
            hits = nxt.result()
            nxt = pool.submit(r.trace, poses[i + 1]) if i + 1 < len(poses) else None
            rgb, depth = r.render(T, noise.stream(seed, noise.FRAME, i), _blur_poses(scene, i), hits=hits)
            yield i, rgb, depth


def params_record(scene: SimScene) -> dict:
    p = scene.params
    c = scene.colon
    return {
        "generator": "datamodules.synthetic",
        "format_version": FORMAT_VERSION,
        "seed": p.seed,
        "preset": p.preset,
        "params": p.to_dict(),
        "paper_table": dict(PAPER_TABLE[p.preset], **PAPER_COMMON) if p.preset in PAPER_TABLE else None,
        "units": "metres, radians inside the code; params: lengths in m, angles in degrees",
        "camera": scene.camera.to_dict(),
        "mesh": {"vertices": int(len(c.vertices)), "triangles": int(len(c.triangles)), "length_m": c.length},
        "folds": [{"s": f.s, "sigma": f.sigma, "heights": list(f.heights)} for f in c.folds],
        "polyps": [{"s": q.s, "theta": q.theta, "radius": q.radius, "height": q.height} for q in c.polyps],
        "events": {k: int(sum(1 for x in scene.path.labels if x == k)) for k in ("closeup", "burst", "occluded", "roll")},
    }


def generate_sequence(
    params: SimParams,
    out: str | Path,
    *,
    overwrite: bool = False,
    progress: bool = True,
    layout: str = "c3f",
    on_frame: Callable[[int], None] | None = None,
) -> Path:
    """Render ``params`` into the folder ``out``; returns its path.

    ``layout``: ``c3f`` (the project's own, SPEC §5.2) or, additionally written from the
    same frames, ``uts`` / ``simcol3d`` / ``c3vd`` / ``colon10k`` (see :mod:`datamodules.synthetic.layouts`).
    """
    params.validate()
    layout = check_layout(layout)
    out = check_output(out, overwrite).resolve()
    tmp = staging_dir(out)
    try:
        scene = build_scene(params)
        _write_all(scene, tmp, layout, progress, on_frame)
        move_into_place(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return out


def _write_all(scene: SimScene, root: Path, layout: str, progress: bool, on_frame: Callable[[int], None] | None) -> None:
    from tqdm import tqdm

    p = scene.params
    writer = SequenceWriter(root, scene.camera)
    extra = None
    if layout != "c3f":
        from datamodules.synthetic.layouts import layout_writer

        extra = layout_writer(layout, root / layout, scene)
    pending: deque[Future] = deque()
    with ThreadPoolExecutor(max_workers=1) as pool:  # PNG encoding overlaps the next frame's rendering
        bar = tqdm(total=p.path.frames, desc=f"simulating {root.name.split('.partial-')[0].lstrip('.')}",
                   unit="frame", disable=not progress, leave=False)
        try:
            for i, rgb, depth in render_frames(scene):
                pending.append(pool.submit(writer.write_frame, i, rgb, depth))
                if extra is not None:
                    pending.append(pool.submit(extra.write_frame, i, rgb, depth))
                while len(pending) > 4:
                    pending.popleft().result()
                bar.update(1)
                if on_frame is not None:
                    on_frame(i)
            while pending:
                pending.popleft().result()
        finally:
            bar.close()
    o3d.io.write_triangle_mesh(str(root / "mesh.ply"), scene.colon.to_legacy_mesh(), write_ascii=False,
                               compressed=False, write_vertex_normals=False, write_vertex_colors=False,
                               write_triangle_uvs=False, print_progress=False)
    (root / "params.json").write_text(json.dumps(params_record(scene), indent=2, sort_keys=True) + "\n")
    _write_frames_csv(scene, root / "frames.csv")
    if extra is not None:
        extra.finish()
    stamps = np.arange(p.path.frames, dtype=np.float64) / p.path.fps
    writer.finish(scene.path.poses, stamps)


def _write_frames_csv(scene: SimScene, path: Path) -> None:
    fps = scene.params.path.fps
    lines = ["index,timestamp,s_m,event,wall_distance_mm"]
    for i, (s, label, d) in enumerate(zip(scene.path.controls.s, scene.path.labels, scene.path.wall_distance)):
        lines.append(f"{i},{i / fps:.6f},{s:.6f},{label},{d * 1000:.3f}")
    path.write_text("\n".join(lines) + "\n")


def read_event_labels(root: str | Path) -> list[str]:
    """Per-frame event labels of a generated sequence (frames.csv ``event`` column, in frame
    order; '' = a plain frame); an empty list when the folder has no frames.csv."""
    path = Path(root) / "frames.csv"
    if not path.is_file():
        return []
    with path.open(newline="") as fh:
        rows = sorted(csv.DictReader(fh), key=lambda r: int(r["index"]))
    return [r.get("event") or "" for r in rows]
