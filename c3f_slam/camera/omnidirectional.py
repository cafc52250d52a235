"""The omnidirectional (Scaramuzza / OCamCalib) camera model, and its undistortion to a pinhole.

The model, exactly as C3VD's renderer (``render/Render.cu``, ``pixel2Ray``) produced the
ground truth: a pixel (u, v), integers at pixel centres, maps to sensor coordinates (x, y) by

    [u - cx, v - cy] = A [x, y],   A = [[c, e], [d, 1]]

(C3VD builds the stretch matrix as ``glm::mat2(c, d, e, 1)``, which glm fills column by
column; its example Python loader writes [[c, d], [e, 1]] instead, a difference of about
3 px at the image edge for the published values), and to the camera-frame ray

    (x, y, a0 + a2 rho^2 + a3 rho^3 + a4 rho^4),   rho = |(x, y)|

(x right, y down, z forward; there is no linear term, a1 = 0). Depth in C3VD is z along this
camera's optical axis, so undistorting it to a pinhole camera with the same axis keeps the
values (only the pixel grid changes).

camera.json of such a lens (``"model": "omnidirectional"``; read by
:meth:`c3f_slam.camera.intrinsics.PinholeCamera.from_json`, written by :meth:`OmniCamera.to_dict`),
all eleven fields required:

- ``width``, ``height``: the frames' size, pixels (integers);
- ``cx``, ``cy``: the pixel of the optical axis (pixels, OpenCV's convention: integer
  coordinates at pixel centres); it must lie inside the frame;
- ``a0`` (pixels, > 0), ``a2`` (1/pixel), ``a3`` (1/pixel^2), ``a4`` (1/pixel^3): the polynomial
  above, rho in sensor pixels (an ``a1`` key, if present, must be 0);
- ``c``, ``d``, ``e``: the stretch matrix A (no unit; 1, 0, 0 for square pixels), not singular;
- ``depth_scale`` (optional, default 10000): depth-PNG units per metre, as for a pinhole.

Undistortion (:class:`c3f_slam.camera.calibration.Undistortion`) remaps frames to a pinhole
camera of the same size, square pixels, principal point at the image centre, sharing the lens's
optical axis, whose focal length is :meth:`OmniCamera.inner_focal`: the smallest for which every
pixel of the pinhole image lies inside the lens's frame (pixel centres in [0, W-1] x [0, H-1])
where the model has an image: no black border, like OpenCV's fisheye balance 0.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, replace
from typing import ClassVar

import numpy as np

from c3f_core.errors import InputError

#: camera.json's fields of an omnidirectional camera (module docstring), all required
FIELDS = ("width", "height", "cx", "cy", "a0", "a2", "a3", "a4", "c", "d", "e")


@dataclass(frozen=True)
class OmniCamera:
    """Scaramuzza omnidirectional intrinsics (pixels; polynomial in sensor pixels; module docstring).

    ``depth_scale``: depth-PNG units per metre, as :class:`~c3f_slam.camera.intrinsics.PinholeCamera`'s."""

    width: int
    height: int
    cx: float
    cy: float
    a0: float
    a2: float
    a3: float
    a4: float
    c: float = 1.0
    d: float = 0.0
    e: float = 0.0
    depth_scale: float = 10000.0

    #: camera.json's ``model`` of this lens
    model: ClassVar[str] = "omnidirectional"
    #: frames of this lens are always undistorted
    is_distorted: ClassVar[bool] = True

    def __post_init__(self) -> None:
        if self.width <= 0 or self.height <= 0:
            raise InputError(f"omnidirectional camera size must be positive, got {self.width}x{self.height}")
        for k in (*FIELDS[2:], "depth_scale"):
            if not math.isfinite(getattr(self, k)):
                raise InputError(f"omnidirectional camera {k} must be finite, got {getattr(self, k)}")
        if not self.a0 > 0:
            raise InputError(f"omnidirectional camera a0 must be positive (rays along +z), got {self.a0}")
        if abs(self.c - self.d * self.e) < 1e-9:
            raise InputError(f"omnidirectional camera stretch matrix (c, d, e) = ({self.c}, {self.d}, {self.e}) "
                             "is singular (c = d e)")
        if not self.depth_scale > 0:
            raise InputError(f"omnidirectional camera depth_scale must be positive, got {self.depth_scale}")

    # ------------------------------------------------------------------ camera.json
    @classmethod
    def from_dict(cls, data: dict) -> OmniCamera:
        """The camera of camera.json's fields (module docstring); InputError naming the field."""
        missing = [k for k in FIELDS if k not in data]
        if missing:
            raise InputError(f"missing key(s) {', '.join(missing)} (an omnidirectional camera needs "
                             f"{', '.join(FIELDS)})")
        values = {}
        for k in (*FIELDS, "a1", "depth_scale"):
            if k not in data:
                continue
            v = data[k]
            if isinstance(v, bool) or not isinstance(v, int | float):
                raise InputError(f"{k} must be a number, got {v!r}")
            values[k] = float(v)
        for k in ("width", "height"):
            if not (math.isfinite(values[k]) and values[k] == int(values[k])):
                raise InputError(f"{k} must be a whole number of pixels, got {data[k]!r}")
        if values.pop("a1", 0.0) != 0.0:
            raise InputError(f"a1 = {data['a1']} (the model has no linear term; a1 must be 0)")
        values["width"], values["height"] = int(values["width"]), int(values["height"])
        return cls(**values).check_plausible()

    def to_dict(self) -> dict:
        """The camera.json fields (:meth:`from_dict` reads them back)."""
        return {"model": self.model, **asdict(self)}

    def check_plausible(self) -> OmniCamera:
        """Self, or InputError when the optical axis (cx, cy) is not inside the frame (no pinhole
        view of the lens would fit inside it)."""
        for name, c, size in (("cx", self.cx, self.width), ("cy", self.cy, self.height)):
            if not 0.0 < c < size - 1:
                raise InputError(f"{name}={c:g} px is not inside the {self.width}x{self.height} frame (the optical "
                                 "axis must be)")
        return self

    def describe(self) -> str:
        """The lens, for summary.json's ``camera_source``."""
        return ("omnidirectional lens " + ", ".join(f"{k}={getattr(self, k)!r}" for k in FIELDS[2:]))

    # ------------------------------------------------------------------ frames
    @property
    def size(self) -> tuple[int, int]:
        """(width, height) in pixels."""
        return self.width, self.height

    def check_image(self, shape: tuple[int, ...], what: str) -> None:
        """Raise InputError unless an (H, W[, C]) array matches this camera's size."""
        h, w = shape[:2]
        if (w, h) != (self.width, self.height):
            raise InputError(f"{what}: image is {w}x{h} but the camera intrinsics are for {self.width}x{self.height}")

    # ------------------------------------------------------------------ geometry
    @property
    def stretch(self) -> np.ndarray:
        """A: sensor (x, y) -> pixel offset (u - cx, v - cy)."""
        return np.array([[self.c, self.e], [self.d, 1.0]])

    def scaled(self, width: int, height: int) -> OmniCamera:
        """The same camera for frames resized to ``width`` x ``height`` (same aspect ratio)."""
        if (width, height) == (self.width, self.height):
            return self
        s, sy = width / self.width, height / self.height
        if abs(s - sy) > 0.01 * s:
            raise InputError(f"frames of {width}x{height} do not have the calibration's aspect ratio "
                             f"({self.width}x{self.height})")
        return replace(self, width=width, height=height, cx=(self.cx + 0.5) * s - 0.5, cy=(self.cy + 0.5) * s - 0.5,
                       a0=self.a0 * s, a2=self.a2 / s, a3=self.a3 / s**2, a4=self.a4 / s**3)

    def _z(self, rho: np.ndarray) -> np.ndarray:
        return self.a0 + rho**2 * (self.a2 + rho * (self.a3 + rho * self.a4))

    def unproject(self, uv: np.ndarray) -> np.ndarray:
        """(N, 2) pixels (u, v) -> (N, 3) float64 unit camera-frame rays."""
        uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
        xy = np.linalg.solve(self.stretch, (uv - [self.cx, self.cy]).T)
        rays = np.stack([xy[0], xy[1], self._z(np.hypot(xy[0], xy[1]))])
        return (rays / np.linalg.norm(rays, axis=0)).T

    def pixel_rays(self) -> np.ndarray:
        """(3, H*W) float64 unit camera-frame rays of every pixel (row-major). Rays more than
        90 degrees off the axis (z < 0) exist: C3VD's lens sees more than a hemisphere at the
        frame corners."""
        u, v = np.meshgrid(np.arange(self.width, dtype=np.float64), np.arange(self.height, dtype=np.float64))
        return self.unproject(np.stack([u.ravel(), v.ravel()], axis=1)).T

    def _angle_table(self) -> tuple[np.ndarray, np.ndarray]:
        """(angle from the optical axis, rho) on a fine grid, as far as the angle grows with rho."""
        w, h = self.width - 1, self.height - 1
        corners = np.array([[0, 0], [w, 0], [0, h], [w, h]], float)
        xy = np.linalg.solve(self.stretch, (corners - [self.cx, self.cy]).T)
        rho = np.linspace(0.0, 1.5 * float(np.hypot(xy[0], xy[1]).max()), 20001)
        theta = np.arctan2(rho, self._z(rho))
        rising = np.flatnonzero(np.diff(theta) <= 0)
        end = int(rising[0]) + 1 if rising.size else len(rho)
        return theta[:end], rho[:end]

    def project(self, points: np.ndarray) -> np.ndarray:
        """(N, 3) camera-frame points -> (N, 2) pixels (u, v); NaN where the model has no image."""
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        r = np.hypot(p[:, 0], p[:, 1])
        theta = np.arctan2(r, p[:, 2])
        table_theta, table_rho = self._angle_table()
        rho = np.interp(theta, table_theta, table_rho, right=np.nan)
        scale = np.divide(rho, r, out=np.zeros_like(r), where=r > 0)
        xy = np.stack([p[:, 0] * scale, p[:, 1] * scale])
        uv = (self.stretch @ xy).T + [self.cx, self.cy]
        uv[~np.isfinite(rho)] = np.nan
        return uv

    # ------------------------------------------------------------------ undistortion to a pinhole
    def undistort_maps(self, pinhole) -> tuple[np.ndarray, np.ndarray]:
        """``cv2.remap`` maps (float32, pinhole-sized) from ``pinhole`` pixels (a
        :class:`~c3f_slam.camera.intrinsics.PinholeCamera` sharing this lens's optical axis) into
        this camera's frames; pixels the frames do not cover map outside (remap fills them with 0)."""
        u, v = np.meshgrid(np.arange(pinhole.width, dtype=np.float64), np.arange(pinhole.height, dtype=np.float64))
        rays = np.stack([(u - pinhole.cx) / pinhole.fx, (v - pinhole.cy) / pinhole.fy, np.ones_like(u)], axis=-1)
        uv = self.project(rays.reshape(-1, 3))
        uv[~np.isfinite(uv)] = -1e6
        shape = (pinhole.height, pinhole.width)
        return uv[:, 0].reshape(shape).astype(np.float32), uv[:, 1].reshape(shape).astype(np.float32)

    def _inside(self, offsets: np.ndarray, focal: float) -> bool:
        """Whether pinhole pixels at ``offsets`` (N, 2) from the principal point, focal ``focal``,
        all land inside the frame."""
        uv = self.project(np.concatenate([offsets / focal, np.ones((len(offsets), 1))], axis=1))
        return bool(np.all(np.isfinite(uv)) and np.all(uv >= 0) and np.all(uv <= [self.width - 1, self.height - 1]))

    def inner_focal(self, max_fov_deg: float = 170.0) -> float:
        """The smallest focal length (pixels) of a pinhole camera of this size, square pixels and
        principal point at the image centre, whose every pixel lies inside this lens's frame
        (balance 0: no black border), but at least the one of ``max_fov_deg`` degrees across the
        wider axis. Its border pixels decide (the interior lies inside their image)."""
        w, h = self.width, self.height
        cx, cy = (w - 1) / 2.0, (h - 1) / 2.0
        us, vs = np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64)
        border = np.concatenate([np.stack([us, np.zeros(w)], 1), np.stack([us, np.full(w, h - 1.0)], 1),
                                 np.stack([np.zeros(h), vs], 1), np.stack([np.full(h, w - 1.0), vs], 1)])
        offsets = border - [cx, cy]
        lo = (max(w, h) / 2.0) / math.tan(math.radians(max_fov_deg) / 2.0)  # the widest pinhole allowed
        lo *= 1.0 + 1e-9
        if self._inside(offsets, lo):
            return lo
        hi = self.a0
        for _ in range(60):
            if self._inside(offsets, hi):
                break
            hi *= 2.0
        else:
            raise InputError(f"no pinhole view of the omnidirectional camera fits inside its {w}x{h} frame")
        while hi / lo > 1.0 + 1e-7:  # bisection (geometric): lo outside, hi inside
            mid = math.sqrt(lo * hi)
            lo, hi = (lo, mid) if self._inside(offsets, mid) else (mid, hi)
        return hi
