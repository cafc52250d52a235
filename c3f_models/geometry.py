"""Differentiable camera geometry in torch, for training.

Same conventions as :mod:`c3f_slam.geometry` (the NumPy half):
- poses are 4x4 matrices; ``T_ij`` maps frame-j coordinates into frame i (p_i = T_ij p_j);
- camera frame x right, y down, z forward; depth is z in metres;
- pixel (u, v) with integer coordinates is the pixel *centre* (OpenCV), so sampling uses
  ``grid_sample(..., align_corners=True)``;
- axis-angle vectors are radians (norm = angle).

Batched shapes: images (B, C, H, W), depth (B, 1, H, W), K (B, 3, 3), poses (B, 4, 4).
"""

from __future__ import annotations

from typing import NamedTuple

import torch
import torch.nn.functional as F
from kornia.geometry.conversions import axis_angle_to_rotation_matrix


def pixel_grid(height: int, width: int, device=None, dtype=torch.float32) -> torch.Tensor:
    """(3, H*W) homogeneous pixel coordinates (u, v, 1), row-major."""
    v, u = torch.meshgrid(
        torch.arange(height, device=device, dtype=dtype),
        torch.arange(width, device=device, dtype=dtype),
        indexing="ij",
    )
    return torch.stack([u.reshape(-1), v.reshape(-1), torch.ones_like(u).reshape(-1)], dim=0)


def backproject(depth: torch.Tensor, K: torch.Tensor) -> torch.Tensor:
    """(B, 1, H, W) depth to (B, 3, H, W) camera-frame points."""
    b, _, h, w = depth.shape
    pix = pixel_grid(h, w, depth.device, depth.dtype)  # (3, HW)
    rays = torch.linalg.inv(K) @ pix.unsqueeze(0)  # (B, 3, HW)
    return (rays * depth.reshape(b, 1, -1)).reshape(b, 3, h, w)


def transform_points(T: torch.Tensor, points: torch.Tensor) -> torch.Tensor:
    """Apply (B, 4, 4) transforms to (B, 3, H, W) points."""
    b, _, h, w = points.shape
    p = points.reshape(b, 3, -1)
    return (T[:, :3, :3] @ p + T[:, :3, 3:]).reshape(b, 3, h, w)


def project(points: torch.Tensor, K: torch.Tensor, eps: float = 1e-7) -> tuple[torch.Tensor, torch.Tensor]:
    """(B, 3, H, W) camera-frame points to pixels (B, 2, H, W) and depth z (B, 1, H, W)."""
    b, _, h, w = points.shape
    p = K @ points.reshape(b, 3, -1)
    z = p[:, 2:3]
    uv = p[:, :2] / z.clamp(min=eps)
    return uv.reshape(b, 2, h, w), z.reshape(b, 1, h, w)


def invert_pose(T: torch.Tensor) -> torch.Tensor:
    """Inverse of rigid transforms (..., 4, 4) using R^T."""
    R = T[..., :3, :3]
    t = T[..., :3, 3:]
    Rt = R.transpose(-1, -2)
    out = torch.zeros_like(T)
    out[..., :3, :3] = Rt
    out[..., :3, 3:] = -Rt @ t
    out[..., 3, 3] = 1.0
    return out


def pose_from_axis_angle(axis_angle: torch.Tensor, translation: torch.Tensor) -> torch.Tensor:
    """(B, 3) axis-angle (radians) and (B, 3) translation (metres) to (B, 4, 4) poses."""
    R = axis_angle_to_rotation_matrix(axis_angle)
    T = torch.zeros(axis_angle.shape[0], 4, 4, device=axis_angle.device, dtype=axis_angle.dtype)
    T[:, :3, :3] = R
    T[:, :3, 3] = translation
    T[:, 3, 3] = 1.0
    return T


def pixels_to_grid(uv: torch.Tensor, height: int, width: int) -> torch.Tensor:
    """(B, 2, H, W) pixel coordinates to a grid_sample grid (B, H, W, 2) in [-1, 1]."""
    u = 2.0 * uv[:, 0] / max(width - 1, 1) - 1.0
    v = 2.0 * uv[:, 1] / max(height - 1, 1) - 1.0
    return torch.stack([u, v], dim=-1)


class Warp(NamedTuple):
    """Result of warping a source view into a target view.

    image: source colour resampled at the target pixels (B, C, H, W).
    sampled_depth: source depth resampled at the target pixels (B, 1, H, W); ``D~`` in SC-SfMLearner's notation.
    projected_depth: depth of the target's points seen from the source camera (B, 1, H, W).
    valid: (B, 1, H, W) bool, the point lands inside the source image in front of the camera.
    """

    image: torch.Tensor
    sampled_depth: torch.Tensor | None
    projected_depth: torch.Tensor
    valid: torch.Tensor


def warp(
    source: torch.Tensor,
    target_depth: torch.Tensor,
    T_source_target: torch.Tensor,
    K: torch.Tensor,
    source_depth: torch.Tensor | None = None,
    padding_mode: str = "border",
) -> Warp:
    """Inverse-warp ``source`` into the target view using the target's depth.

    ``T_source_target`` maps target-camera coordinates into the source camera.
    """
    b, _, h, w = target_depth.shape
    pts = transform_points(T_source_target, backproject(target_depth, K))
    uv, z = project(pts, K)
    grid = pixels_to_grid(uv, h, w)
    image = F.grid_sample(source, grid, mode="bilinear", padding_mode=padding_mode, align_corners=True)
    sampled = None
    if source_depth is not None:
        sampled = F.grid_sample(source_depth, grid, mode="bilinear", padding_mode=padding_mode, align_corners=True)
    inside = (grid.abs() <= 1.0).all(dim=-1, keepdim=True).permute(0, 3, 1, 2)
    valid = inside & (z > 1e-6)
    return Warp(image, sampled, z, valid)
