"""Intrinsics of a real camera: checkerboard calibration, and undoing lens distortion.

``python -m c3f_slam calibrate INPUT --out camera.json --board COLSxROWS --square METRES``
(:func:`calibrate_command`): INPUT is a folder of checkerboard images or a checkerboard video.
The board's inner corners are found (``cv2.findChessboardCorners``, refined to sub-pixel with
``cv2.cornerSubPix``) and the camera is fitted with ``cv2.calibrateCamera`` (``pinhole``: k1,
k2, p1, p2, k3) or ``cv2.fisheye.calibrate`` (``fisheye``: k1..k4). The result is a camera.json
of the project's format (:class:`c3f_slam.camera.intrinsics.PinholeCamera`: pixels, OpenCV's camera
frame). ``--board`` counts *inner* corners (a board of 10 x 7 squares is 9x6); ``--square`` is
the side of a square in metres (it sets the scale of the board poses, not the intrinsics).

:class:`Undistortion` turns frames of a distorted camera (a fisheye or pinhole distortion, or an
omnidirectional lens: :mod:`c3f_slam.camera.omnidirectional`) into pinhole frames of the same size
(remap maps computed once); :class:`c3f_slam.frames.stream.FrameStream` applies it to every frame.
"""

from __future__ import annotations

import json
import re
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from c3f_core.atomic import atomic_write_text
from c3f_core.errors import InputError
from c3f_slam.camera.intrinsics import MAX_PINHOLE_FOV_DEG, PinholeCamera
from c3f_slam.camera.omnidirectional import OmniCamera
from c3f_slam.io.sequence import IMAGE_SUFFIXES, read_rgb

MODELS = ("pinhole", "fisheye")
#: fewest views with the board found that a calibration is fitted from
MIN_VIEWS = 3
#: most views fitted: more (a video's near-duplicate frames) are thinned evenly to this many
MAX_VIEWS = 40
CALIBRATION_SUFFIXES = (*IMAGE_SUFFIXES, ".bmp", ".tif", ".tiff")
_FIND_FLAGS = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_FAST_CHECK
_SUBPIX_CRITERIA = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 40, 1e-3)
_FIT_CRITERIA = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 200, 1e-10)


# ------------------------------------------------------------------ the board
def parse_board(text: str) -> tuple[int, int]:
    """(columns, rows) of inner corners from ``COLSxROWS``, e.g. ``9x6``; InputError naming --board."""
    m = re.fullmatch(r"\s*(\d+)\s*[xX]\s*(\d+)\s*", text or "")
    if not m or min(int(m.group(1)), int(m.group(2))) < 2:
        raise InputError(f"--board must be COLSxROWS inner corners, each at least 2 (e.g. 9x6 for a board of "
                         f"10 x 7 squares), got {text!r}")
    return int(m.group(1)), int(m.group(2))


def board_points(board: tuple[int, int], square: float) -> np.ndarray:
    """(cols * rows, 3) float32 corner positions on the board plane z = 0, metres, in the order
    ``findChessboardCorners`` returns them (row by row, ``cols`` corners a row)."""
    cols, rows = board
    x, y = np.meshgrid(np.arange(cols), np.arange(rows))
    return np.stack([x.ravel(), y.ravel(), np.zeros(cols * rows)], axis=1).astype(np.float32) * np.float32(square)


def find_corners(gray: np.ndarray, board: tuple[int, int]) -> np.ndarray | None:
    """(cols * rows, 1, 2) float32 sub-pixel inner corners of the board in a grey image, or None."""
    found, corners = cv2.findChessboardCorners(gray, board, flags=_FIND_FLAGS)
    if not found:
        return None
    spacing = float(np.min(np.linalg.norm(np.diff(corners.reshape(board[1], board[0], 2), axis=1), axis=2)))
    half = int(np.clip(0.4 * spacing, 2, 11))  # the search window stays inside the corner's squares
    return cv2.cornerSubPix(gray, corners, (half, half), (-1, -1), _SUBPIX_CRITERIA)


# ------------------------------------------------------------------ reading the views
def iter_views(source: Path, every: int = 1) -> Iterator[tuple[str, np.ndarray]]:
    """(name, grey uint8 image) of every ``every``-th image of a folder (sorted by name) or frame of
    a video. InputError for an unreadable image, a video that does not open, or no images."""
    if source.is_dir():
        files = sorted(p for p in source.iterdir() if p.suffix.lower() in CALIBRATION_SUFFIXES)
        if not files:
            raise InputError(f"{source}: no images ({', '.join(CALIBRATION_SUFFIXES)}) to calibrate from")
        for path in files[::every]:
            yield str(path), cv2.cvtColor(read_rgb(path), cv2.COLOR_RGB2GRAY)
        return
    if not source.is_file():
        raise InputError(f"{source}: no such file or folder")
    cap = cv2.VideoCapture(str(source))
    try:
        if not cap.isOpened():
            raise InputError(f"{source}: not a folder of images or a video that opens (unsupported codec or "
                             "corrupt file)")
        index = 0
        while True:
            if index % every:
                if not cap.grab():
                    return
            else:
                ok, bgr = cap.read()
                if not ok or bgr is None:
                    return
                yield f"{source} frame {index}", cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)
            index += 1
    finally:
        cap.release()


@dataclass(frozen=True)
class Views:
    """The board corners found: per view its name and (N, 1, 2) float32 pixels; the image size."""

    names: list[str]
    corners: list[np.ndarray]
    size: tuple[int, int]  #: (width, height) pixels
    tried: int  #: images or frames looked at


def collect_views(source: Path, board: tuple[int, int], every: int = 1) -> Views:
    """Find the board in the views of ``source``; InputError when the sizes differ or fewer than
    :data:`MIN_VIEWS` views show the whole board. At most :data:`MAX_VIEWS` are kept, evenly spread."""
    names: list[str] = []
    corners: list[np.ndarray] = []
    size: tuple[int, int] | None = None
    first = ""
    tried = 0
    for name, gray in iter_views(source, every):
        tried += 1
        h, w = gray.shape
        if size is None:
            size, first = (w, h), name
        elif (w, h) != size:
            raise InputError(f"{name}: image is {w}x{h} but {first} is {size[0]}x{size[1]}; calibrate views of "
                             "one camera at one size")
        found = find_corners(gray, board)
        if found is not None:
            names.append(name)
            corners.append(found)
    if size is None:
        raise InputError(f"{source}: no frame could be read")
    if len(corners) < MIN_VIEWS:
        raise InputError(f"{source}: the {board[0]}x{board[1]} board was found in {len(corners)} of {tried} views, "
                         f"at least {MIN_VIEWS} needed (--board counts inner corners; the whole board must be in view)")
    if len(corners) > MAX_VIEWS:
        keep = np.unique(np.linspace(0, len(corners) - 1, MAX_VIEWS).round().astype(int))
        names, corners = [names[i] for i in keep], [corners[i] for i in keep]
    return Views(names, corners, size, tried)


# ------------------------------------------------------------------ fitting
@dataclass(frozen=True)
class Calibration:
    """A fitted camera, its RMS reprojection error (pixels) and the views it used."""

    camera: PinholeCamera
    rms: float
    views: Views


def fit_camera(views: Views, board: tuple[int, int], square: float, model: str = "pinhole") -> Calibration:
    """Fit ``model`` (pinhole: k1, k2, p1, p2, k3; fisheye: k1..k4) to the corners of ``views``."""
    if model not in MODELS:
        raise InputError(f"--model must be one of {', '.join(MODELS)}, got {model!r}")
    obj = board_points(board, square)
    w, h = views.size
    try:
        if model == "pinhole":
            rms, K, D, _, _ = cv2.calibrateCamera([obj] * len(views.corners), views.corners, views.size, None, None,
                                                  criteria=_FIT_CRITERIA)
        else:
            flags = cv2.fisheye.CALIB_RECOMPUTE_EXTRINSIC | cv2.fisheye.CALIB_FIX_SKEW
            rms, K, D, _, _ = cv2.fisheye.calibrate(
                [obj.reshape(-1, 1, 3).astype(np.float64)] * len(views.corners),
                [c.reshape(-1, 1, 2).astype(np.float64) for c in views.corners], views.size,
                np.zeros((3, 3)), np.zeros((4, 1)), flags=flags, criteria=_FIT_CRITERIA)
    except cv2.error as exc:
        reason = str(exc).strip().splitlines()[-1][:160]
        raise InputError(f"the {model} calibration did not converge on {len(views.corners)} views ({reason}); "
                         "more views with the board at different angles help") from None
    try:
        camera = PinholeCamera(w, h, float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2]),
                               distortion=tuple(float(d) for d in np.ravel(D)), model=model).check_plausible()
    except InputError as exc:
        raise InputError(f"the {model} calibration gave an impossible camera ({exc}); more views with the board at "
                         "different angles, or the other --model, may help") from None
    return Calibration(camera, float(rms), views)


def calibrate_command(source: str | Path, out: str | Path, board: str, square: float, model: str = "pinhole",
                      every: int = 1) -> Calibration:
    """Calibrate from the checkerboard views of ``source`` and write ``out`` (camera.json)."""
    if not (square > 0 and np.isfinite(square)):
        raise InputError(f"--square must be the side of a board square in metres (> 0), got {square:g}")
    if every < 1:
        raise InputError(f"--every must be >= 1, got {every}")
    if model not in MODELS:
        raise InputError(f"--model must be one of {', '.join(MODELS)}, got {model!r}")
    corners = parse_board(board)
    result = fit_camera(collect_views(Path(source), corners, every), corners, square, model)
    atomic_write_text(Path(out), json.dumps(result.camera.to_dict(), indent=2) + "\n")
    return result


# ------------------------------------------------------------------ undistortion
class Undistortion:
    """Remaps frames of a distorted camera (``lens``) to the pinhole ``camera`` of the same size.

    The new focal length keeps every output pixel inside the lens's image (OpenCV's
    ``getOptimalNewCameraMatrix`` with alpha 0, ``fisheye.estimateNewCameraMatrixForUndistortRectify``
    with balance 0; an omnidirectional lens: :meth:`OmniCamera.inner_focal
    <c3f_slam.camera.omnidirectional.OmniCamera.inner_focal>`, the principal point at the image
    centre): no black border, a narrower field of view than the lens. Depth is remapped with the
    nearest pixel, so values stay z-depths (the optical axis is the same)."""

    #: the focal length grows by this factor until every pixel of the pinhole image lies inside the lens's
    #: image (OpenCV's estimate can leave slivers of border)
    ZOOM_STEP = 1.01

    def __init__(self, lens: PinholeCamera | OmniCamera) -> None:
        self.lens = lens
        if isinstance(lens, OmniCamera):
            self.camera = PinholeCamera.centred(lens.width, lens.height, lens.inner_focal(MAX_PINHOLE_FOV_DEG),
                                                depth_scale=lens.depth_scale)
            self.maps = lens.undistort_maps(self.camera)
            return
        D = np.asarray(lens.distortion, np.float64)
        if lens.model == "fisheye":
            K = cv2.fisheye.estimateNewCameraMatrixForUndistortRectify(lens.K, D, lens.size, np.eye(3), balance=0.0)
        else:
            K, _ = cv2.getOptimalNewCameraMatrix(lens.K, D, lens.size, 0.0, lens.size)
        for _ in range(50):
            self.maps = self._maps(K, D)
            mx, my = self.maps
            if mx.min() >= 0 and my.min() >= 0 and mx.max() <= lens.width - 1 and my.max() <= lens.height - 1:
                break
            K = K @ np.diag([self.ZOOM_STEP, self.ZOOM_STEP, 1.0])  # the principal point stays
        self.camera = PinholeCamera(lens.width, lens.height, float(K[0, 0]), float(K[1, 1]), float(K[0, 2]),
                                    float(K[1, 2]), depth_scale=lens.depth_scale)

    def _maps(self, K: np.ndarray, D: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``cv2.remap`` maps (float32, frame-sized): pixels of the pinhole camera ``K`` in the lens's frame."""
        lens = self.lens
        init = cv2.fisheye.initUndistortRectifyMap if lens.model == "fisheye" else cv2.initUndistortRectifyMap
        return init(lens.K, D, np.eye(3), K, lens.size, cv2.CV_32FC1)

    @classmethod
    def of(cls, lens: PinholeCamera | OmniCamera) -> Undistortion | None:
        """The undistortion of ``lens``, or None when its frames are pinhole frames already."""
        return cls(lens) if lens.is_distorted else None

    def rgb(self, image: np.ndarray) -> np.ndarray:
        """A frame of the lens (H, W[, C]) as the pinhole camera sees it (bilinear)."""
        return cv2.remap(image, *self.maps, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)

    def depth(self, depth: np.ndarray) -> np.ndarray:
        """A depth map (H, W) float32 metres of the lens in the pinhole camera (nearest pixel, 0 = none)."""
        return cv2.remap(depth, *self.maps, cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT)

    def describe(self) -> str:
        """For summary.json's ``camera_source``."""
        if isinstance(self.lens, OmniCamera):
            return f"{self.lens.describe()}, frames undistorted to pinhole"
        return f"{self.lens.model} lens with distortion {list(self.lens.distortion)}, frames undistorted to pinhole"
