"""Colon10K (UNC, Ma et al. 2021), read as published: real colonoscopy frames, no ground truth.

Layout::

    <seq>/image/*.jpg                 undistorted frames, 270 x 216
    calib_270_216.txt                 (some copies, beside the sequences or in them) DSO-style:
                                      "Pinhole fx fy cx cy 0" then "270 216"
    <seq>-matchings.txt ...           place-recognition labels (not read)

Conventions chosen where the sources are ambiguous (each pinned by a test):

- Frames are ordered by the last number in their file names (names without a number: by name).
- **Intrinsics**: a given ``calibration`` file, else a ``calib_<W>_<H>.txt`` for the frames' size
  in the sequence folder or the folder above it, else the published values for 270 x 216
  frames (fx = fy = 145.4410, cx = 135.6993, cy = 107.8946, no distortion: the frames come
  undistorted). Frames of another size without a calibration file are an error.
- No depth, no poses: Colon10K trains DepthNet self-supervised only; the paper splits it 80/20
  by sequence (the data module's defaults).
"""

from __future__ import annotations

from pathlib import Path

from c3f_core.errors import InputError
from c3f_slam.camera.intrinsics import PinholeCamera
from datamodules.formats.base import PublishedSequence, SequenceFormat, decode_rgb, list_files, numbered

PUBLISHED = PinholeCamera(270, 216, 145.4410, 145.4410, 135.6993, 107.8946)
IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png")


def read_calibration(path: Path) -> PinholeCamera:
    """A DSO-style calibration: ``<model> fx fy cx cy [k...]`` then ``W H`` (absolute pixels;
    the model must be a pinhole: no distortion terms, or zeros)."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: calibration file not found")
    lines = [ln.split() for ln in path.read_text(errors="replace").splitlines() if ln.strip()]
    if len(lines) < 2:
        raise InputError(f"{path}: expected '<model> fx fy cx cy' and 'width height' lines")
    head, size = lines[0], lines[1]
    try:
        nums = [float(x) for x in (head[1:] if not _is_number(head[0]) else head)]
        w, h = int(size[0]), int(size[1])
    except (ValueError, IndexError):
        raise InputError(f"{path}: expected '<model> fx fy cx cy' and 'width height' lines") from None
    if len(nums) < 4:
        raise InputError(f"{path}: expected fx fy cx cy on the first line, got {len(nums)} numbers")
    if any(abs(k) > 1e-12 for k in nums[4:]):
        raise InputError(f"{path}: distortion terms {nums[4:]} (Colon10K frames are undistorted; "
                         "undistort them first)")
    if max(nums[:4]) < 1.0:
        raise InputError(f"{path}: relative intrinsics (DSO's values < 1) are not supported; give pixels")
    try:
        return PinholeCamera(w, h, *nums[:4])
    except InputError as exc:
        raise InputError(f"{path}: {exc}") from None


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


class Colon10KSequence(PublishedSequence):
    dataset = "Colon10K"


class Colon10KFormat(SequenceFormat):
    """Colon10K sequences; ``calibration``: a calibration file for every sequence."""

    name = "colon10k"
    title = "Colon10K"
    layout = "<seq>/image/*.jpg (270 x 216, undistorted)"

    def __init__(self, calibration: str | Path | None = None) -> None:
        self.calibration = read_calibration(Path(calibration)) if calibration is not None else None

    def is_sequence(self, folder: Path) -> bool:
        return bool(list_files(folder / "image", IMAGE_SUFFIXES))

    def _camera(self, folder: Path, width: int, height: int, first: Path) -> PinholeCamera:
        cam = self.calibration
        if cam is None:
            for parent in (folder, folder.parent):
                path = parent / f"calib_{width}_{height}.txt"
                if path.is_file():
                    cam = read_calibration(path)
                    break
        if cam is None:
            if (width, height) != PUBLISHED.size:
                raise InputError(f"{first}: frames are {width}x{height}; Colon10K's published intrinsics are for "
                                 f"270x216 (give a calibration file)")
            cam = PUBLISHED
        if cam.size != (width, height):
            raise InputError(f"{first}: frames are {width}x{height} but the calibration is for "
                             f"{cam.width}x{cam.height}")
        return cam

    def open(self, folder: Path) -> Colon10KSequence:
        folder = Path(folder)
        files = list_files(folder / "image", IMAGE_SUFFIXES)
        if not files:
            raise InputError(f"{folder}: not a Colon10K sequence (expected image/*.jpg)")
        by_number = numbered(files)
        paths = list(by_number.values()) if len(by_number) == len(files) else files
        h, w = decode_rgb(paths[0]).shape[:2]
        return Colon10KSequence(folder.name, folder, self._camera(folder, w, h, paths[0]), paths, None, None)
