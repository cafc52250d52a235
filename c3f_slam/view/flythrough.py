"""``flythrough.mp4``: the final model seen from a camera gliding along the smoothed camera path.

The registered camera positions are resampled by arc length (``samples``), smoothed (a
Gaussian of ``smooth_share`` of the path length) and resampled again to the video's ``frames``,
so the camera moves at constant speed; it looks along the path's direction of travel, with the
run's own camera "up" (smoothed the same way) kept up. The model is ray cast on the CPU with a
wide-angle pinhole (``fov_deg``, ``width`` x ``height`` pixels) and a light at the eye that fades
with distance, as an endoscope's does. The names are the fields of
:class:`c3f_slam.view.settings.FlythroughSettings`.
"""

from __future__ import annotations

import time
from collections.abc import Iterator

import numpy as np
from scipy.ndimage import gaussian_filter1d

from c3f_slam.camera.intrinsics import PinholeCamera
from c3f_slam.evaluation.trajectory import path_length
from c3f_slam.geometry import look_at
from c3f_slam.view.raycast import MeshScene, render_pinhole
from c3f_slam.view.rerender import RenderClock
from c3f_slam.view.settings import FlythroughSettings
from c3f_slam.view.video import label


def _by_arc_length(points: np.ndarray, n: int) -> np.ndarray:
    """(n, D) points evenly spaced along the polyline through the first 3 columns of ``points``."""
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(points[:, :3], axis=0), axis=1))])
    t = np.linspace(0, s[-1], n)
    return np.stack([np.interp(t, s, points[:, k]) for k in range(points.shape[1])], axis=1)


def smoothed_path(poses: np.ndarray, fly: FlythroughSettings | None = None
                  ) -> tuple[np.ndarray, np.ndarray, float] | None:
    """(eyes (``fly.frames``, 3), ups (``fly.frames``, 3), path length in metres) along the
    smoothed path of the camera-to-world ``poses`` (metres; ``fly``: default the defaults); None
    when the camera did not move."""
    fly = fly or FlythroughSettings()
    pos = poses[:, :3, 3]
    if path_length(pos) <= 0:
        return None
    both = _by_arc_length(np.concatenate([pos, -poses[:, :3, 1]], axis=1), fly.samples)  # position, camera up
    smooth = gaussian_filter1d(both, fly.smooth_share * fly.samples, axis=0, mode="nearest")
    out = _by_arc_length(smooth, fly.frames)
    return out[:, :3], out[:, 3:], path_length(out[:, :3])


def _camera_poses(eyes: np.ndarray, ups: np.ndarray) -> list[np.ndarray]:
    """Camera-to-world poses looking along the direction of travel (the last one keeps going)."""
    ahead = np.gradient(eyes, axis=0)
    poses, last = [], None
    for eye, d, up in zip(eyes, ahead, ups):
        try:
            last = look_at(eye, eye + d, up)
        except ValueError:  # standing still or looking straight up: keep the previous view
            if last is None:
                continue
            last = last.copy()
            last[:3, 3] = eye
        poses.append(last)
    return poses


def flythrough_frames(ms: MeshScene, poses: np.ndarray, clock: RenderClock,
                      fly: FlythroughSettings | None = None) -> Iterator[np.ndarray]:
    """The fly-through's RGB frames, ``fly.width`` x ``fly.height`` pixels (nothing when the
    camera did not move; ``fly``: default the defaults)."""
    fly = fly or FlythroughSettings()
    path = smoothed_path(poses, fly)
    if path is None:
        return
    eyes, ups, length = path
    cam = PinholeCamera.from_fov(fly.width, fly.height, fly.fov_deg)
    falloff = max(0.3 * length, 1e-3)
    cams = _camera_poses(eyes, ups)
    for i, T in enumerate(cams):
        t0 = time.perf_counter()
        img, _ = render_pinhole(ms, cam.K, T, fly.width, fly.height, falloff=falloff, ambient=0.5)
        clock.seconds += time.perf_counter() - t0
        clock.frames += 1
        label(img, f"fly-through: {100 * length * i / max(1, len(cams) - 1):.1f} of {100 * length:.1f} cm",
              corner="bottom")
        yield img
