"""Pinhole camera intrinsics and how they follow crops and resizes.

Convention (OpenCV): pixel (u, v) with integer coordinates is the *centre* of the pixel
in column u and row v; the image spans [-0.5, W-0.5] x [-0.5, H-0.5]. Focal lengths and
principal point are in pixels. Depth is metres along the optical axis (z), camera frame
x right, y down, z forward.

Lens distortion (``model`` and ``distortion``, OpenCV's conventions): ``pinhole`` with 0, 4,
5, 8, 12 or 14 coefficients (k1, k2, p1, p2[, k3[, k4, k5, k6[, s1..s4[, tx, ty]]]]), or
``fisheye`` (OpenCV's equidistant model) with exactly k1..k4. A camera.json may instead describe
an ``omnidirectional`` (Scaramuzza / OCamCalib) lens, read as a
:class:`c3f_slam.camera.omnidirectional.OmniCamera` (its fields: that module). The runtime
undistorts such frames to a pinhole camera (:class:`c3f_slam.camera.calibration.Undistortion`).
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np

from c3f_core.errors import InputError
from c3f_slam.camera.omnidirectional import OmniCamera

_REQUIRED = ("width", "height", "fx", "fy", "cx", "cy")

#: lens models of a PinholeCamera's ``model`` and their allowed numbers of distortion coefficients
DISTORTION_COUNTS = {"pinhole": (0, 4, 5, 8, 12, 14), "fisheye": (4,)}
#: camera.json's ``model`` values: those and the omnidirectional lens (an OmniCamera)
LENS_MODELS = (*DISTORTION_COUNTS, OmniCamera.model)
#: widest field of view (degrees, per image axis) taken for a pinhole camera: beyond it the image is
#: mostly stretched border (a wider lens needs its fisheye model), and values in normalised units
#: or millimetres instead of pixels land here
MAX_PINHOLE_FOV_DEG = 170.0


@dataclass(frozen=True)
class PinholeCamera:
    """Intrinsics of a pinhole camera (pixels), optional distortion, depth PNG scale.

    ``depth_scale`` is the number of depth-PNG units per metre (uint16 PNG value =
    depth_m * depth_scale); it only matters for reading and writing depth files.
    """

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    distortion: tuple[float, ...] = field(default_factory=tuple)
    depth_scale: float = 10000.0
    model: str = "pinhole"  #: lens model of ``distortion``: pinhole | fisheye (module docstring)

    def __post_init__(self) -> None:
        if self.width <= 0 or self.height <= 0:
            raise InputError(f"camera size must be positive, got {self.width}x{self.height}")
        for name in ("fx", "fy"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise InputError(f"camera {name} must be a positive finite number, got {v}")
        for name in ("cx", "cy"):
            if not math.isfinite(getattr(self, name)):
                raise InputError(f"camera {name} must be finite, got {getattr(self, name)}")
        if not (self.depth_scale > 0):
            raise InputError(f"camera depth_scale must be positive, got {self.depth_scale}")
        if self.model == OmniCamera.model:
            raise InputError("an omnidirectional camera is an OmniCamera (c3f_slam.camera.omnidirectional), "
                             "not a PinholeCamera")
        if self.model not in DISTORTION_COUNTS:
            raise InputError(f"camera model must be one of {', '.join(LENS_MODELS)}, got {self.model!r}")
        counts = DISTORTION_COUNTS[self.model]
        if len(self.distortion) not in counts:
            raise InputError(f"a {self.model} camera takes {' or '.join(map(str, counts))} distortion coefficients, "
                             f"got {len(self.distortion)}")
        if not all(math.isfinite(d) for d in self.distortion):
            raise InputError(f"camera distortion coefficients must be finite, got {list(self.distortion)}")

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_fov(cls, width: int, height: int, fov_deg: float, **kw: float) -> PinholeCamera:
        """Camera with square pixels whose *horizontal* field of view is ``fov_deg`` degrees."""
        if not 0 < fov_deg < 180:
            raise InputError(f"field of view must be in (0, 180) degrees, got {fov_deg}")
        return cls.centred(width, height, (width / 2.0) / math.tan(math.radians(fov_deg) / 2.0), **kw)

    @classmethod
    def centred(cls, width: int, height: int, focal: float, **kw: float) -> PinholeCamera:
        """Camera with square pixels of ``focal`` pixels and the principal point at the image centre."""
        return cls(width, height, focal, focal, (width - 1) / 2.0, (height - 1) / 2.0, **kw)

    @classmethod
    def from_json(cls, path: str | Path) -> PinholeCamera | OmniCamera:
        """Read ``camera.json`` of the project's sequence layout (docs/datasets.md, Sequence layout):
        the runtime's one reader of camera files. ``"model": "omnidirectional"`` gives an
        :class:`~c3f_slam.camera.omnidirectional.OmniCamera` (a lens the frames are undistorted
        from), any other model a PinholeCamera. InputError: one line naming the file and field."""
        path = Path(path)
        if not path.is_file():
            raise InputError(f"{path}: camera file not found")
        try:
            data = json.loads(path.read_text())
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise InputError(f"{path}: not valid JSON ({exc})") from None
        if not isinstance(data, dict):
            raise InputError(f"{path}: not a JSON object of camera fields")
        if data.get("model") == OmniCamera.model:
            try:
                return OmniCamera.from_dict(data)
            except InputError as exc:
                raise InputError(f"{path}: {exc}") from None
        missing = [k for k in _REQUIRED if k not in data]
        if missing:
            raise InputError(f"{path}: missing key(s) {', '.join(missing)}")
        try:
            return cls(
                width=int(data["width"]),
                height=int(data["height"]),
                fx=float(data["fx"]),
                fy=float(data["fy"]),
                cx=float(data["cx"]),
                cy=float(data["cy"]),
                distortion=tuple(float(d) for d in data.get("distortion", []) or []),
                depth_scale=float(data.get("depth_scale", 10000.0)),
                model=str(data.get("model") or "pinhole"),
            ).check_plausible()
        except InputError as exc:
            raise InputError(f"{path}: {exc}") from None
        except (TypeError, ValueError) as exc:
            raise InputError(f"{path}: bad value ({exc})") from None

    def to_dict(self) -> dict:
        """The camera.json fields (:meth:`from_json` reads them back)."""
        d = asdict(self)
        d["distortion"] = list(self.distortion)
        return d

    def check_plausible(self) -> PinholeCamera:
        """Self, or InputError when no real camera has these intrinsics: the principal point
        more than a quarter of the image outside it, or a pinhole that would see
        :data:`MAX_PINHOLE_FOV_DEG` degrees or more across an axis (fx, fy not in pixels?)."""
        for name, c, size in (("cx", self.cx, self.width), ("cy", self.cy, self.height)):
            if not -0.25 * size - 0.5 <= c <= 1.25 * size - 0.5:
                raise InputError(f"principal point {name}={c:g} px is far outside the {self.width}x{self.height} "
                                 "image")
        if self.model == "pinhole":
            fov = max(self.fov_deg())
            if fov >= MAX_PINHOLE_FOV_DEG:
                raise InputError(f"fx={self.fx:g}, fy={self.fy:g} px give a pinhole field of view of {fov:.1f} "
                                 f"degrees (at most {MAX_PINHOLE_FOV_DEG:g}): focal lengths must be in pixels, and "
                                 "a wider lens needs \"model\": \"fisheye\"")
        return self

    @property
    def is_distorted(self) -> bool:
        """True when frames must be undistorted to be a pinhole image (a fisheye, or non-zero coefficients)."""
        return self.model != "pinhole" or any(d != 0.0 for d in self.distortion)

    # ------------------------------------------------------------------ properties
    @property
    def K(self) -> np.ndarray:
        """3x3 intrinsic matrix (float64)."""
        return np.array(
            [[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]], dtype=np.float64
        )

    @property
    def size(self) -> tuple[int, int]:
        """(width, height) in pixels."""
        return self.width, self.height

    def fov_deg(self) -> tuple[float, float]:
        """Horizontal and vertical field of view in degrees."""
        return (
            math.degrees(2 * math.atan(self.width / (2 * self.fx))),
            math.degrees(2 * math.atan(self.height / (2 * self.fy))),
        )

    # ------------------------------------------------------------------ image ops
    def crop(self, x0: int, y0: int, width: int, height: int) -> PinholeCamera:
        """Intrinsics of the sub-image whose top-left pixel is (x0, y0)."""
        return replace(self, width=width, height=height, cx=self.cx - x0, cy=self.cy - y0)

    def resize(self, width: int, height: int) -> PinholeCamera:
        """Intrinsics after resizing the whole image to ``width`` x ``height``."""
        sx, sy = width / self.width, height / self.height
        return replace(
            self,
            width=width,
            height=height,
            fx=self.fx * sx,
            fy=self.fy * sy,
            cx=(self.cx + 0.5) * sx - 0.5,
            cy=(self.cy + 0.5) * sy - 0.5,
        )

    def center_crop_box(self, crop_width: int, crop_height: int) -> tuple[int, int, int, int]:
        """(x0, y0, w, h) of a centred crop; raises if the crop is larger than the image."""
        if crop_width > self.width or crop_height > self.height:
            raise InputError(
                f"crop {crop_width}x{crop_height} is larger than the image {self.width}x{self.height}"
            )
        return (self.width - crop_width) // 2, (self.height - crop_height) // 2, crop_width, crop_height

    def check_image(self, shape: tuple[int, ...], what: str) -> None:
        """Raise InputError unless an (H, W[, C]) array matches this camera's size."""
        h, w = shape[:2]
        if (w, h) != (self.width, self.height):
            raise InputError(
                f"{what}: image is {w}x{h} but the camera intrinsics are for {self.width}x{self.height}"
            )


@dataclass(frozen=True)
class FovGuess:
    """No calibration: a pinhole camera of ``degrees`` horizontal field of view, square pixels and
    the principal point at the centre, for frames of whatever size the video has (``--fov``)."""

    degrees: float

    def __post_init__(self) -> None:
        if not (math.isfinite(self.degrees) and 0 < self.degrees < MAX_PINHOLE_FOV_DEG):
            raise InputError(f"--fov must be between 0 and {MAX_PINHOLE_FOV_DEG:g} degrees (a pinhole camera's "
                             f"horizontal field of view), got {self.degrees:g}")

    def camera(self, width: int, height: int) -> PinholeCamera:
        """The guessed intrinsics for ``width`` x ``height`` frames (pixels)."""
        try:
            return PinholeCamera.from_fov(width, height, self.degrees).check_plausible()
        except InputError as exc:
            raise InputError(f"--fov {self.degrees:g} on {width}x{height} frames: {exc}") from None

    def describe(self) -> str:
        """What summary.json's ``camera_source`` says."""
        return f"fov guess {self.degrees:g} deg"
