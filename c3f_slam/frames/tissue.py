"""The image area that shows tissue: the scope's border and burned-in overlays left out.

A real colonoscopy recording shows the colon inside a black border (a circle, an octagon, cut
corners, letterboxing) and carries burned-in text, a clock and icons that do not move with
the scene. Neither is surface: depth, keypoints, descriptors, fusion and the unseen-wall
estimate use only the tissue area, a run constant (H, W) bool mask of the frame grid
(True = tissue), held by :class:`TissueMask`.

Where it comes from (:func:`resolve_tissue_mask`, in this order): a mask image given by
``tissue.file``, one named by ``camera.json``'s ``tissue_mask`` field (a path relative to the
camera file), else detected from the first frames of the run (:func:`detect_tissue_mask`) unless
``tissue.mode`` is ``off``. A mask image is a PNG of the frame size, white (> 127) = tissue.

Detection uses temporal statistics of up to ``tissue.frames`` frames spread over the first
``tissue.window`` frames of the stream:

- *lit* pixels are those some sample shows brighter than ``tissue.dark_level`` (luma 0..255):
  the border never is; the dark lumen moves and is lit in some sample;
- *moving* pixels change by more than ``tissue.static_level`` between at least
  ``tissue.moving_share`` of consecutive samples: tissue under a moving scope does, text and
  icons do not (a clock's digits change once a second, between few samples);
- the scope's field of view is convex (every common border shape is), so the tissue area is the
  convex hull of the largest connected region of lit, moving pixels, found on a thumbnail and
  drawn at full resolution;
- overlays inside it are the static pixels with a sharp edge in the temporal median (text and
  icons are sharp; a still stretch of smooth mucosa is not; the border's own edge is removed by
  filling the median outside the hull first), closed over their glyphs and filled;
- the mask is eroded by ``tissue.margin`` (a share of the smaller image side) to drop the soft,
  compressed edge of the border, where keypoints would not move with the scene.

A mask covering at least ``tissue.full_share`` of the frame means no border: the run then uses
the whole frame exactly as without a mask. When the samples barely move (the scope held still
at the start), overlays cannot be told from tissue: the hull of the lit pixels is used alone and
``TissueMask.source`` says so.
"""

from __future__ import annotations

import copy
import json
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from c3f_core.errors import InputError
from c3f_slam.config import TissueConfig
from c3f_slam.frames.preprocess import fill_outside

#: detection runs on frames scaled down to at most this many pixels on the long side
THUMBNAIL_PX = 256
#: a sample is "barely moving" when fewer than this share of its lit pixels move
MIN_MOVING_SHARE = 0.3


@dataclass(frozen=True)
class TissueMask:
    """The tissue area of a run's frames: ``pixels`` (H, W) bool (True = tissue) in the frame
    grid, ``source`` how it was found (``detected``, ``detected (border only: ...)``, ``file``,
    ``camera.json``, ``whole frame``), ``frames`` the frames detection used (0 otherwise),
    ``overlay_share`` the share of the frame taken out as overlays inside the border, ``path`` the
    mask file read (None when detected)."""

    pixels: np.ndarray
    source: str
    frames: int = 0
    overlay_share: float = 0.0
    path: str | None = None

    @property
    def share(self) -> float:
        """Share of the frame's pixels that show tissue (0..1)."""
        return float(self.pixels.mean())

    @property
    def whole_frame(self) -> bool:
        """True when every pixel is tissue (the run then behaves exactly as without a mask)."""
        return bool(self.pixels.all())

    def summary(self) -> dict:
        """summary.json's ``tissue_mask``."""
        out = {"share": round(self.share, 4), "source": self.source, "frames": self.frames,
               "overlay_share": round(self.overlay_share, 4), "file": "tissue_mask.png"}
        if self.path is not None:
            out["path"] = self.path
        return out

    def write_png(self, path: str | Path) -> None:
        """The mask as an 8-bit PNG (255 = tissue), the format :func:`read_mask_png` reads."""
        if not cv2.imwrite(str(path), self.pixels.astype(np.uint8) * 255):
            raise OSError(f"could not write {path}")


def whole_frame(width: int, height: int) -> TissueMask:
    """Every pixel is tissue (no border)."""
    return TissueMask(np.ones((height, width), bool), "whole frame")


# ---------------------------------------------------------------------------------- files
def read_mask_png(path: str | Path, width: int, height: int, what: str = "tissue mask") -> np.ndarray:
    """(H, W) bool of a mask image (white > 127 = tissue); InputError naming the file when it is
    missing, not an image, of another size than the frames (``width`` x ``height``), or empty."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: {what} not found")
    img = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if img is None:
        raise InputError(f"{path}: {what} is not a readable image")
    if img.shape != (height, width):
        raise InputError(f"{path}: {what} is {img.shape[1]}x{img.shape[0]} but the frames are {width}x{height}")
    mask = img > 127
    if not mask.any():
        raise InputError(f"{path}: {what} is empty (no white pixel = no tissue)")
    return mask


def camera_mask_file(camera_json: str | Path | None) -> Path | None:
    """The mask image named by ``camera.json``'s ``tissue_mask`` field (relative to the camera
    file), or None."""
    if camera_json is None:
        return None
    path = Path(camera_json)
    try:
        name = json.loads(path.read_text()).get("tissue_mask")
    except (OSError, ValueError, AttributeError):
        return None  # the camera reader reports a bad camera.json itself
    if not name:
        return None
    if not isinstance(name, str):
        raise InputError(f"{path}: tissue_mask must be a file name, got {name!r}")
    return path.parent / name


# ---------------------------------------------------------------------------------- detection
def _thumbnail(rgb: np.ndarray, scale: float) -> np.ndarray:
    grey = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
    if scale == 1.0:
        return grey
    h, w = grey.shape
    return cv2.resize(grey, (max(1, round(w * scale)), max(1, round(h * scale))), interpolation=cv2.INTER_AREA)


def _largest_component(mask: np.ndarray) -> np.ndarray:
    n, labels, stats, _ = cv2.connectedComponentsWithStats(mask.astype(np.uint8), connectivity=8)
    if n <= 1:
        return np.zeros_like(mask, dtype=bool)
    best = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
    return labels == best


def _hull_mask(region: np.ndarray, scale: float, width: int, height: int) -> np.ndarray:
    """The convex hull of ``region`` (thumbnail grid) drawn at full resolution (pixel centres
    mapped through the thumbnail's half-pixel convention; the hull grown by half a thumbnail
    pixel so a region reaching the thumbnail's edge reaches the frame's)."""
    ys, xs = np.nonzero(region)
    pts = np.stack([xs, ys], axis=1).astype(np.float32)
    hull = cv2.convexHull(pts)[:, 0, :]
    centre = hull.mean(axis=0)
    grown = hull + 0.5 * np.sign(hull - centre)  # half a thumbnail pixel outwards
    full = (grown + 0.5) / scale - 0.5
    out = np.zeros((height, width), np.uint8)
    cv2.fillConvexPoly(out, np.round(full * 16).astype(np.int32), 1, lineType=cv2.LINE_8, shift=4)
    return out.astype(bool)


def _overlays(stack: np.ndarray, static: np.ndarray, hull: np.ndarray, cfg: TissueConfig) -> np.ndarray:
    """Static pixels inside ``hull`` with a sharp edge in the temporal median, closed over their
    glyphs and filled (thumbnail grid). Outside the hull the median is first filled from the
    inside, so the border's own static edge is no overlay."""
    median = np.median(stack, axis=0).astype(np.uint8)
    median = fill_outside(np.repeat(median[..., None], 3, axis=2), hull)[..., 0].astype(np.float32)
    gx = cv2.Sobel(median, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(median, cv2.CV_32F, 0, 1, ksize=3)
    sharp = np.hypot(gx, gy) > cfg.overlay_edge
    seeds = (static & sharp & hull).astype(np.uint8)
    if not seeds.any():
        return seeds.astype(bool)
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (5, 5))
    closed = cv2.morphologyEx(seeds, cv2.MORPH_CLOSE, kernel)
    contours, _ = cv2.findContours(closed, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    cv2.drawContours(closed, contours, -1, 1, thickness=cv2.FILLED)  # the flat inside of an icon too
    return cv2.dilate(closed, np.ones((3, 3), np.uint8)).astype(bool)


def detect_tissue_mask(frames: list[np.ndarray], cfg: TissueConfig) -> TissueMask:
    """The tissue area of (H, W, 3) uint8 RGB ``frames`` of one recording (see the module notes).
    InputError when fewer than 2 frames are given or nothing in them is lit."""
    if len(frames) < 2:
        raise InputError(f"tissue mask detection needs at least 2 readable frames, got {len(frames)} "
                         "(tissue.mode=off, or give a mask with tissue.file)")
    height, width = frames[0].shape[:2]
    scale = min(1.0, THUMBNAIL_PX / max(width, height))
    stack = np.stack([_thumbnail(f, scale) for f in frames]).astype(np.int16)
    lit = stack.max(axis=0) > cfg.dark_level
    if not lit.any():
        raise InputError("tissue mask detection: no pixel of the first frames is lit (all darker than "
                         f"tissue.dark_level {cfg.dark_level}); give a mask with tissue.file")
    changes = np.abs(np.diff(stack, axis=0)) > cfg.static_level
    moving = changes.mean(axis=0) >= cfg.moving_share
    moving_share = float((moving & lit).sum() / lit.sum())
    if moving_share >= MIN_MOVING_SHARE:
        region, source = _largest_component(lit & moving), "detected"
        static = lit & ~moving
    else:  # the scope barely moves in the samples: the lit pixels alone, no overlay detection
        region = _largest_component(lit)
        source = f"detected (border only: {moving_share:.0%} of the lit pixels move in the first frames)"
        static = np.zeros_like(lit)
    hull = _hull_mask(region, scale, width, height)
    overlays = np.zeros_like(hull)
    if static.any():
        small = _overlays(stack, static, _hull_mask(region, 1.0, *lit.shape[::-1]), cfg).astype(np.uint8)
        overlays = cv2.resize(small, (width, height), interpolation=cv2.INTER_NEAREST).astype(bool) & hull
    mask = hull & ~overlays
    margin = int(round(cfg.margin * min(width, height)))
    if margin > 0 and mask.mean() < cfg.full_share:
        kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * margin + 1, 2 * margin + 1))
        mask = cv2.erode(mask.astype(np.uint8), kernel, borderType=cv2.BORDER_REPLICATE).astype(bool)
    if mask.mean() >= cfg.full_share:
        return TissueMask(np.ones((height, width), bool), "whole frame (detected: no border)", len(frames))
    return TissueMask(mask, source, len(frames), float(overlays.mean()))


def sample_frames(stream, count: int, window: int) -> list[np.ndarray]:
    """Up to ``count`` usable RGB frames of ``stream`` (a :class:`c3f_slam.frames.stream.FrameStream`),
    evenly spread over its first ``window`` frames (its own start and stride), read through a
    copy so the stream itself is untouched."""
    probe = copy.copy(stream)
    probe.quality = None
    total = window if stream.max_frames is None else min(window, stream.max_frames)
    probe.step = stream.step * max(1, total // max(1, count))
    probe.max_frames = count
    return [f.rgb for f in probe if f.usable]


def resolve_tissue_mask(stream, cfg: TissueConfig, camera_json: str | Path | None = None) -> TissueMask:
    """The tissue area of a run's frames: ``cfg.file``, else the mask ``camera_json`` names,
    else detected from the stream's first frames (``cfg.mode`` auto), else the whole frame."""
    width, height = stream.camera.width, stream.camera.height
    given = Path(cfg.file) if cfg.file else camera_mask_file(camera_json)
    if cfg.mode == "off":
        return whole_frame(width, height)
    if given is not None:
        what = "tissue.file" if cfg.file else f"tissue mask named by {camera_json}"
        pixels = read_mask_png(given, width, height, what)
        return TissueMask(pixels, "file" if cfg.file else "camera.json", path=str(given))
    frames = sample_frames(stream, cfg.frames, cfg.window)
    if len(frames) < 2:  # a very short input, or one that starts dark: nothing to tell the border by
        return TissueMask(np.ones((height, width), bool), f"whole frame (detection needs 2 usable frames, "
                                                          f"the first {cfg.window} have {len(frames)})", len(frames))
    return detect_tissue_mask(frames, cfg)
