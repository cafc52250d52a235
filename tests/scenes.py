"""Analytic test scenes with exact depth and poses (no simulator needed).

``plane_sequence`` renders a textured plane z = ``distance`` (world frame) seen by a camera
translating sideways: depth, poses and images are exact, so warping tests know the answer.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from c3f_slam import geometry as g
from c3f_slam.camera import PinholeCamera
from c3f_slam.io import SequenceWriter


def plane_texture(size: int = 512, seed: int = 0) -> np.ndarray:
    """A smooth random RGB texture (uint8) with blobs at several scales."""
    rng = np.random.default_rng(seed)
    tex = np.zeros((size, size, 3), np.float32)
    for cells in (4, 16, 64):
        noise = rng.random((cells, cells, 3)).astype(np.float32)
        tex += cv2.resize(noise, (size, size), interpolation=cv2.INTER_CUBIC) / 3
    tex = (tex - tex.min()) / (tex.max() - tex.min())
    return (40 + 180 * tex).astype(np.uint8)


def render_plane(
    camera: PinholeCamera, T_wc: np.ndarray, texture: np.ndarray, distance: float, extent: float
) -> tuple[np.ndarray, np.ndarray]:
    """Render the plane z_w = distance, textured over [-extent, extent]^2 (metres)."""
    K_inv = np.linalg.inv(camera.K)
    u, v = np.meshgrid(np.arange(camera.width), np.arange(camera.height))
    rays_c = np.stack([u, v, np.ones_like(u)], -1).reshape(-1, 3) @ K_inv.T
    rays_w = rays_c @ T_wc[:3, :3].T
    o = T_wc[:3, 3]
    s = (distance - o[2]) / rays_w[:, 2]
    hit = o + s[:, None] * rays_w
    depth = (s * rays_c[:, 2]).reshape(camera.height, camera.width).astype(np.float32)
    n = texture.shape[0]
    mapx = ((hit[:, 0] + extent) / (2 * extent) * (n - 1)).reshape(camera.height, camera.width)
    mapy = ((hit[:, 1] + extent) / (2 * extent) * (n - 1)).reshape(camera.height, camera.width)
    img = cv2.remap(texture, mapx.astype(np.float32), mapy.astype(np.float32), cv2.INTER_LINEAR,
                    borderMode=cv2.BORDER_REFLECT)
    return img, depth


def plane_sequence(
    root: Path, frames: int = 6, size: int = 48, distance: float = 0.05, step: float = 0.002, seed: int = 0
) -> Path:
    """Write a sequence in the project's layout: a plane 5 cm away, camera moving along x."""
    cam = PinholeCamera.from_fov(size, size, 90.0)
    tex = plane_texture(seed=seed)
    writer = SequenceWriter(root, cam)
    poses = []
    for i in range(frames):
        T = g.make_pose(g.axis_angle_to_matrix([0.0, 0.01 * i, 0.0]), [step * i, 0.0, 0.0])
        img, depth = render_plane(cam, T, tex, distance, extent=0.1)
        writer.write_frame(i, img, depth)
        poses.append(T)
    writer.finish(np.stack(poses))
    return root
