"""Analytic test scenes with exact depth and poses (no simulator needed).

``plane_sequence`` renders a textured plane z = ``distance`` (world frame) seen by a camera
translating sideways: depth, poses and images are exact, so warping tests know the answer.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from c3f_slam import geometry as g
from c3f_slam.camera.intrinsics import PinholeCamera
from c3f_slam.io import SequenceWriter
from datamodules.synthetic.noise import blob_texture as plane_texture


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


def tube_mesh(length: float = 0.1, radius: float = 0.025, fold: tuple[float, float, float] | None = None,
              margin: float = 0.02, ds: float = 0.0005, n_theta: int = 180, drop=None):
    """Open3D mesh of a straight tube along world +z from -``margin`` to ``length`` + ``margin``
    (metres), radius ``radius``; ``fold`` = (s0, height as a fraction of the radius, sigma):
    a ring ridge r = R (1 - h exp(-(z - s0)^2 / 2 sigma^2)). ``drop(z, theta)`` -> bool removes
    the triangles whose first vertex it flags (a hole, as fusion leaves unseen wall)."""
    import open3d as o3d

    z = np.arange(-margin, length + margin + ds / 2, ds)
    th = np.linspace(-np.pi, np.pi, n_theta, endpoint=False)
    Z, TH = np.meshgrid(z, th, indexing="ij")
    R = np.full_like(Z, radius)
    if fold is not None:
        s0, h, sigma = fold
        R = radius * (1 - h * np.exp(-((Z - s0) ** 2) / (2 * sigma**2)))
    V = np.stack([R * np.cos(TH), R * np.sin(TH), Z], axis=-1).reshape(-1, 3)
    i, j = np.meshgrid(np.arange(len(z) - 1), np.arange(n_theta), indexing="ij")
    a, b = i * n_theta + j, i * n_theta + (j + 1) % n_theta
    c, d = a + n_theta, b + n_theta
    F = np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3), np.stack([b, d, c], -1).reshape(-1, 3)])
    if drop is not None:
        F = F[~drop(V[F[:, 0], 2], np.arctan2(V[F[:, 0], 1], V[F[:, 0], 0]))]
    mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(V), o3d.utility.Vector3iVector(F))
    mesh.vertex_colors = o3d.utility.Vector3dVector(np.tile([0.8, 0.4, 0.35], (len(V), 1)))
    return mesh.remove_unreferenced_vertices()


def tube_views(stations: np.ndarray, angles_deg: np.ndarray | None = None) -> np.ndarray:
    """Camera-to-world poses on the axis of :func:`tube_mesh` at heights ``stations`` (metres):
    looking radially at each of ``angles_deg`` (image up = +z), or along +z when None."""
    poses = []
    for zc in stations:
        eye = np.array([0.0, 0.0, zc])
        if angles_deg is None:
            poses.append(g.look_at(eye, eye + [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]))
            continue
        for a in np.radians(angles_deg):
            poses.append(g.look_at(eye, eye + [np.cos(a), np.sin(a), 0.0], [0.0, 0.0, 1.0]))
    return np.stack(poses)
