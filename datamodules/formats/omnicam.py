"""C3VD's omnidirectional (Scaramuzza / OCamCalib) camera: its calibration file, its published
calibration, and the pinhole camera the C3VD reader undistorts frames to.

The model itself, with its conventions (pixel centres at integers; the stretch matrix
A = [[c, e], [d, 1]] as C3VD's renderer builds it with ``glm::mat2(c, d, e, 1)``, filled
column by column, not the [[c, d], [e, 1]] of C3VD's example Python loader; rays
(x, y, a0 + a2 rho^2 + a3 rho^3 + a4 rho^4), x right, y down, z forward; depth is z along
the optical axis, kept by the undistortion), is the runtime's
:class:`c3f_slam.camera.omnidirectional.OmniCamera`; :class:`OmniCamera` here adds only C3VD's
``key = value`` calibration file (``camera_intrinsics.txt`` of C3VDv2) and the converter's
pinhole choice (focal a0 by default).
"""

from __future__ import annotations

from dataclasses import asdict
from pathlib import Path

from c3f_core.errors import InputError
from c3f_slam.camera import omnidirectional
from c3f_slam.camera.intrinsics import PinholeCamera

_KEYS = omnidirectional.FIELDS


class OmniCamera(omnidirectional.OmniCamera):
    """The runtime's omnidirectional camera (pixels; polynomial in sensor pixels), read from and
    written to C3VD's calibration files."""

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

    # ------------------------------------------------------------------ the converter's pinhole
    def pinhole(self, focal: float | None = None, depth_scale: float = 10000.0) -> PinholeCamera:
        """The pinhole camera C3VD frames are undistorted to: same size, principal point at the image
        centre, focal length ``focal`` pixels (default a0: the model's own scale on the axis; the
        runtime's undistortion of a camera.json takes :meth:`inner_focal` instead)."""
        return PinholeCamera.centred(self.width, self.height, self.a0 if focal is None else float(focal),
                                     depth_scale=depth_scale)


#: C3VD's published calibration (the Olympus CF-HQ190L of the C3VD release, values of its
#: ``python/exampleDataLoader.py``). C3VDv2 ships its own ``camera_intrinsics.txt``.
C3VD_CALIBRATION = OmniCamera(
    width=1350, height=1080, cx=678.544839263292, cy=542.975887548343, a0=769.243600037458,
    a2=-0.000812770624150226, a3=6.25674244578925e-07, a4=-1.19662182144280e-09,
    c=0.999986882249990, d=0.00288273829525059, e=-0.00296316513429569,
)
