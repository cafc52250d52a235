"""A synthetic room-scale RGB-D sequence (no real data here): a textured box room with a few
pieces of furniture, rendered with Open3D's RaycastingScene, with Kinect-like depth noise.

Room 5 x 4 x 2.8 m (world z up, metres). Every surface is textured by projecting the hit point
onto the plane of its dominant normal axis and sampling a smooth random texture (one per
object). Depth noise: axial sigma = 1.2 mm + 1.9 mm x (z - 0.4 m)^2 (Nguyen et al. 2012, Kinect
v1; ~0.5 % at 2 m, ~0.6 % at 3 m) and disparity quantisation with a step of 2.85e-3 x z^2 m, then
1 mm PNG quantisation (``depth_scale`` 1000). Camera (OpenCV axes: x right, y down, z forward)
on a closed ellipse at 1.2-1.6 m height looking outwards and sideways, so the path revisits its
start (loop closure). Poses written camera-to-world.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import open3d as o3d

from c3f_slam import geometry as g
from c3f_slam.camera.intrinsics import PinholeCamera
from c3f_slam.io import SequenceWriter
from datamodules.synthetic.noise import blob_texture

ROOM = (5.0, 4.0, 2.8)  #: metres, x, y, z
#: furniture boxes: (size xyz, min corner xyz), metres
FURNITURE = (((1.2, 0.7, 0.75), (0.4, 0.4, 0.0)), ((0.5, 1.5, 1.9), (4.3, 1.0, 0.0)),
             ((0.8, 0.8, 0.45), (2.0, 3.0, 0.0)), ((0.3, 0.3, 1.2), (3.6, 0.3, 0.0)))
TEXTURE_PERIOD = 2.5  #: metres covered by one texture image (it repeats)


def room_scene() -> tuple[o3d.t.geometry.RaycastingScene, list[np.ndarray]]:
    """The scene and one texture (H, W, 3) uint8 per geometry id (room first, its normals inwards)."""
    scene = o3d.t.geometry.RaycastingScene()
    room = o3d.geometry.TriangleMesh.create_box(*ROOM)
    room.triangles = o3d.utility.Vector3iVector(np.asarray(room.triangles)[:, ::-1].copy())
    meshes = [room]
    for size, corner in FURNITURE:
        meshes.append(o3d.geometry.TriangleMesh.create_box(*size).translate(corner))
    for m in meshes:
        scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(m))
    return scene, [blob_texture(1024, seed=10 + n) for n in range(len(meshes))]


def render(scene, textures: list[np.ndarray], camera: PinholeCamera, T_wc: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(RGB (H, W, 3) uint8, exact depth (H, W) metres, 0 = no hit) of camera-to-world ``T_wc``."""
    u, v = np.meshgrid(np.arange(camera.width), np.arange(camera.height))  # pixel centres (cx = (W - 1) / 2)
    rays_c = np.stack([u, v, np.ones_like(u)], -1).reshape(-1, 3) @ np.linalg.inv(camera.K).T
    rays_w = rays_c @ T_wc[:3, :3].T
    rays = np.concatenate([np.broadcast_to(T_wc[:3, 3], rays_w.shape), rays_w], 1).astype(np.float32)
    hit = scene.cast_rays(o3d.core.Tensor(rays))
    t = hit["t_hit"].numpy().astype(np.float64)
    ok = np.isfinite(t)
    gid = np.where(ok, hit["geometry_ids"].numpy().astype(np.int64), 0)
    normal = np.abs(hit["primitive_normals"].numpy())
    p = T_wc[:3, 3] + np.where(ok, t, 0)[:, None] * rays_w
    axis = normal.argmax(1)
    a = np.where(axis == 0, p[:, 1], p[:, 0])
    b = np.where(axis == 2, p[:, 1], p[:, 2])
    rgb = np.zeros((len(t), 3), np.uint8)
    for n, tex in enumerate(textures):
        sel = ok & (gid == n)
        size = tex.shape[0]
        ia = ((a[sel] / TEXTURE_PERIOD + 0.37 * axis[sel]) % 1.0 * (size - 1)).astype(np.int64)
        ib = ((b[sel] / TEXTURE_PERIOD + 0.21 * axis[sel]) % 1.0 * (size - 1)).astype(np.int64)
        shade = 0.75 + 0.25 * (axis[sel] == 2)  # floor/ceiling brighter than walls
        rgb[sel] = (tex[ib, ia] * shade[:, None]).astype(np.uint8)
    depth = np.where(ok, t * rays_c[:, 2], 0.0)
    return rgb.reshape(camera.height, camera.width, 3), depth.reshape(camera.height, camera.width)


def kinect_noise(depth: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Axial noise and disparity quantisation of a Kinect v1 (see the module notes); 0 stays 0."""
    z = depth + rng.normal(size=depth.shape) * (0.0012 + 0.0019 * np.square(np.maximum(depth - 0.4, 0)))
    step = 2.85e-3  # disparity step, 1/m: depth step 2.85e-3 z^2
    with np.errstate(divide="ignore"):
        z = np.where(depth > 0, 1.0 / (np.round(1.0 / np.maximum(z, 1e-3) / step) * step), 0.0)
    return np.where((depth > 0.4) & (depth < 6.0), z, 0.0).astype(np.float32)


def camera_path(frames: int) -> np.ndarray:
    """(frames, 4, 4) camera-to-world poses on a closed ellipse around the room's centre."""
    s = np.linspace(0, 2 * np.pi, frames, endpoint=False)
    cx, cy = ROOM[0] / 2, ROOM[1] / 2
    centre = np.stack([cx + 1.0 * np.cos(s), cy + 0.7 * np.sin(s), 1.4 + 0.2 * np.sin(3 * s)], 1)
    yaw = s + 0.9 + 0.4 * np.sin(2 * s)  # looking outwards and ahead
    pitch = 0.15 * np.sin(5 * s) - 0.1
    poses = []
    for c, y, pt in zip(centre, yaw, pitch, strict=True):
        fwd = np.array([np.cos(y) * np.cos(pt), np.sin(y) * np.cos(pt), np.sin(pt)])
        right = np.cross(fwd, [0.0, 0.0, 1.0])
        right /= np.linalg.norm(right)
        down = np.cross(fwd, right)
        poses.append(g.make_pose(np.stack([right, down, fwd], 1), c))
    return np.stack(poses)


def room_sequence(root: Path, frames: int = 240, width: int = 320, height: int = 240, seed: int = 0,
                  noise: bool = True) -> Path:
    """Write the room sequence in the project's layout (rgb/, depth/, camera.json, poses.txt)."""
    cam = PinholeCamera.from_fov(width, height, 60.0, depth_scale=1000.0)
    scene, textures = room_scene()
    rng = np.random.default_rng(seed)
    writer = SequenceWriter(root, cam)
    poses = camera_path(frames)
    for i, T in enumerate(poses):
        rgb, depth = render(scene, textures, cam, T)
        writer.write_frame(i, rgb, kinect_noise(depth, rng) if noise else depth.astype(np.float32))
    writer.finish(poses)
    return root
