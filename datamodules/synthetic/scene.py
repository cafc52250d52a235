"""One simulated scene: the colon, its texture, the camera path and the renderer of a
parameter set, and the rendering of its frames (deterministic in the seed).

:mod:`datamodules.synthetic.generate` writes a scene's frames as a sequence;
:mod:`datamodules.synthetic.layouts` writes them again in the published layouts.
Lengths in metres, depth in metres, poses camera-to-world.
"""

from __future__ import annotations

from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np
import open3d as o3d

from c3f_slam.camera.intrinsics import PinholeCamera
from datamodules.synthetic import noise
from datamodules.synthetic.camera_path import CameraPath, plan_path
from datamodules.synthetic.colon import Colon, build_colon
from datamodules.synthetic.params import SimParams
from datamodules.synthetic.render import Renderer, make_scene
from datamodules.synthetic.texture import TextureAtlas, build_atlas

__all__ = ["SimScene", "build_scene", "make_camera", "render_frames"]


@dataclass(kw_only=True)
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
    """The pinhole camera of ``params.camera`` (field of view in degrees, depth scale in units per metre)."""
    c = params.camera
    return PinholeCamera.from_fov(c.width, c.height, c.fov, depth_scale=c.depth_scale)


def build_scene(params: SimParams) -> SimScene:
    """Build colon, texture and path of ``params`` (checked when made; deterministic in the seed)."""
    seed = params.seed
    colon = build_colon(params.colon, noise.stream(seed, noise.GEOMETRY))
    raycaster = make_scene(colon)
    path = plan_path(colon, params.path, noise.stream(seed, noise.PATH), raycaster)
    atlas = build_atlas(colon, params.appearance, noise.stream(seed, noise.TEXTURE))
    camera = make_camera(params)
    renderer = Renderer(colon, atlas, camera, params.appearance, scene=raycaster)
    return SimScene(params=params, colon=colon, atlas=atlas, raycaster=raycaster, path=path, camera=camera,
                    renderer=renderer)


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
