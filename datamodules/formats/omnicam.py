"""The omnidirectional (Scaramuzza / OCamCalib) camera of C3VD, and its undistortion to a pinhole.

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
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np

from c3f_core.errors import InputError
from c3f_slam.camera.intrinsics import PinholeCamera

_KEYS = ("width", "height", "cx", "cy", "a0", "a2", "a3", "a4", "c", "d", "e")


@dataclass(frozen=True)
class OmniCamera:
    """Scaramuzza omnidirectional intrinsics (pixels; polynomial in sensor pixels)."""

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

    def __post_init__(self) -> None:
        if self.width <= 0 or self.height <= 0:
            raise InputError(f"omnidirectional camera size must be positive, got {self.width}x{self.height}")
        if not all(math.isfinite(getattr(self, k)) for k in _KEYS[2:]):
            raise InputError("omnidirectional camera parameters must be finite")
        if not self.a0 > 0:
            raise InputError(f"omnidirectional camera a0 must be positive (rays along +z), got {self.a0}")
        if abs(self.c - self.d * self.e) < 1e-9:
            raise InputError("omnidirectional camera stretch matrix (c, d, e) is singular")

    # ------------------------------------------------------------------ files
    @classmethod
    def from_file(cls, path: str | Path) -> OmniCamera:
        """Read ``key = value`` lines (C3VDv2's ``camera_intrinsics.txt``; ';' or '#' start a
        comment): width, height, cx, cy, a0, a1 (must be 0), a2, a3, a4, c, d, e."""
        path = Path(path)
        if not path.is_file():
            raise InputError(f"{path}: calibration file not found")
        values: dict[str, float] = {}
        try:
            lines = path.read_text().splitlines()
        except UnicodeDecodeError:
            raise InputError(f"{path}: calibration is not a text file") from None
        for lineno, raw in enumerate(lines, start=1):
            line = raw.split(";")[0].split("#")[0].strip()
            if not line:
                continue
            key, sep, value = line.partition("=")
            if not sep:
                raise InputError(f"{path}:{lineno}: expected 'key = value', got {raw.strip()[:60]!r}")
            try:
                values[key.strip().lower()] = float(value)
            except ValueError:
                raise InputError(f"{path}:{lineno}: not a number: {value.strip()[:40]!r}") from None
        missing = [k for k in _KEYS if k not in values]
        if missing:
            raise InputError(f"{path}: calibration lacks {', '.join(missing)} (an omnidirectional "
                             "width/height/cx/cy/a0..a4/c/d/e file)")
        if abs(values.get("a1", 0.0)) > 1e-12:
            raise InputError(f"{path}: a1 = {values['a1']} (the model has no linear term; a1 must be 0)")
        try:
            return cls(int(values["width"]), int(values["height"]), *(values[k] for k in _KEYS[2:]))
        except InputError as exc:
            raise InputError(f"{path}: {exc}") from None

    def to_text(self) -> str:
        """The ``key = value`` form :meth:`from_file` reads."""
        d = asdict(self)
        d["a1"] = 0.0
        order = ("width", "height", "cx", "cy", "a0", "a1", "a2", "a3", "a4", "c", "d", "e")
        return "; omnidirectional camera intrinsics\n" + "".join(f"{k} = {d[k]!r}\n" for k in order)

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

    def pixel_rays(self) -> np.ndarray:
        """(3, H*W) float64 unit camera-frame rays of every pixel (row-major). Rays more than
        90 degrees off the axis (z < 0) exist: C3VD's lens sees more than a hemisphere at the
        frame corners."""
        u, v = np.meshgrid(np.arange(self.width, dtype=np.float64), np.arange(self.height, dtype=np.float64))
        xy = np.linalg.solve(self.stretch, np.stack([u.ravel() - self.cx, v.ravel() - self.cy]))
        rays = np.stack([xy[0], xy[1], self._z(np.hypot(xy[0], xy[1]))])
        return rays / np.linalg.norm(rays, axis=0)

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

    def pinhole(self, focal: float | None = None, depth_scale: float = 10000.0) -> PinholeCamera:
        """The pinhole camera frames are undistorted to: same size, principal point at the image
        centre, focal length ``focal`` pixels (default a0: the model's own scale on the axis)."""
        f = self.a0 if focal is None else float(focal)
        return PinholeCamera(self.width, self.height, f, f, (self.width - 1) / 2.0, (self.height - 1) / 2.0,
                             depth_scale=depth_scale)

    def undistort_maps(self, pinhole: PinholeCamera) -> tuple[np.ndarray, np.ndarray]:
        """``cv2.remap`` maps (float32, pinhole-sized) from ``pinhole`` pixels into this camera's
        frames; pixels the frames do not cover map outside (remap fills them with 0)."""
        u, v = np.meshgrid(np.arange(pinhole.width, dtype=np.float64), np.arange(pinhole.height, dtype=np.float64))
        rays = np.stack([(u - pinhole.cx) / pinhole.fx, (v - pinhole.cy) / pinhole.fy, np.ones_like(u)], axis=-1)
        uv = self.project(rays.reshape(-1, 3))
        uv[~np.isfinite(uv)] = -1e6
        shape = (pinhole.height, pinhole.width)
        return uv[:, 0].reshape(shape).astype(np.float32), uv[:, 1].reshape(shape).astype(np.float32)


#: C3VD's published calibration (the Olympus CF-HQ190L of the C3VD release, values of its
#: ``python/exampleDataLoader.py``). C3VDv2 ships its own ``camera_intrinsics.txt``.
C3VD_CALIBRATION = OmniCamera(
    width=1350, height=1080, cx=678.544839263292, cy=542.975887548343, a0=769.243600037458,
    a2=-0.000812770624150226, a3=6.25674244578925e-07, a4=-1.19662182144280e-09,
    c=0.999986882249990, d=0.00288273829525059, e=-0.00296316513429569,
)
