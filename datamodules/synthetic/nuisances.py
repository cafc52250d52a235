"""Nuisances of real colonoscope recordings, applied to the rendered uint8 RGB frames.

Real recordings show the colon inside the scope's black border (a circle, an octagon, cut
corners, letterboxing), carry burned-in text, a running clock and icons that do not move with
the scene, and have motion-blurred, defocused, washed-out (over-exposed) frames and
near-duplicate frames from re-encoding. :class:`NuisanceChain` adds them to a sequence's frames
after rendering, in this order per frame: defocus, motion blur, wash-out (the optics and the
sensor), border, overlay (the video processor); a repeated frame instead takes the previous
output frame's pixels re-encoded as JPEG, with that frame's depth and pose. The geometry is
never touched: depth is only set to 0 outside the tissue mask (the border has no depth).

Settings: :class:`~datamodules.synthetic.params.NuisanceParams` (``SimParams.nuisance``, all
off by default; off, the frames are written exactly as rendered; the options and truth files:
docs/datasets.md, Nuisances of real recordings). Randomness comes from the
sequence seed: :func:`datamodules.synthetic.noise.stream` with stream number
:data:`NUISANCE_STREAM` (per sequence) and ``(NUISANCE_STREAM, i)`` (per frame ``i``), so a
frame's nuisances depend neither on the number of frames nor on the other options' shares.

Sizes are in pixels of the output frame, grey levels in 0..255, times in seconds of video
time (frame index / fps).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from c3f_core.errors import InputError
from datamodules.synthetic.noise import stream
from datamodules.synthetic.params import BORDERS, NuisanceParams

__all__ = ["NAMES", "NUISANCE_STREAM", "NuisanceChain", "NuisanceFrame", "NuisanceParams", "apply_border",
           "burn_in", "clock_text", "defocus", "disc_kernel", "edge_alpha", "jpeg_roundtrip", "line_kernel",
           "motion_blur", "overlay_alpha", "read_nuisances", "tissue_mask", "wash_out"]

#: random stream of the nuisances (after noise.py's GEOMETRY, TEXTURE, PATH, FRAME = 1..4)
NUISANCE_STREAM = 5
#: the names nuisances.json uses, in the order they are listed
NAMES = ("border", "overlay", "motion_blur", "defocus", "washed_out", "repeat")
EDGE_PX = 1.5  # width of the border's soft edge, px (inside the tissue mask)
BORDER_NOISE = 1.2  # std of the border's grey level, grey levels
OVERLAY_GREY = 235  # grey level of burned-in text and icons
SHADOW_GREY = 16  # grey level of their 1-px drop shadow


# ---------------------------------------------------------------------- border
def tissue_mask(width: int, height: int, border: str = "none", scale: float = 1.0, corner: float = 0.15,
                bars: float = 0.2) -> np.ndarray:
    """(H, W) bool, True where the image shows tissue, for a border shape centred in the frame.

    ``circle``: diameter ``scale`` x the smaller side; ``octagon``: regular, ``scale`` x the
    smaller side across its flats; both are clipped by the frame edge when ``scale`` > 1.
    ``cut_corners``: the whole frame less four right-angled corners with legs ``corner`` x the
    smaller side; ``letterbox``: a black bar at top and bottom, the two taking ``bars`` of the
    height. A pixel is tissue when its centre lies inside the shape.
    """
    x = np.arange(width, dtype=np.float64)[None, :] + 0.5 - width / 2  # pixel centres from the frame centre, px
    y = np.arange(height, dtype=np.float64)[:, None] + 0.5 - height / 2
    side = min(width, height)
    if border == "none":
        inside = np.ones((height, width), bool)
    elif border == "circle":
        inside = x * x + y * y <= (0.5 * scale * side) ** 2
    elif border == "octagon":
        a = 0.5 * scale * side  # inradius
        inside = (np.abs(x) <= a) & (np.abs(y) <= a) & (np.abs(x) + np.abs(y) <= a * math.sqrt(2.0))
    elif border == "cut_corners":
        dx, dy = width / 2 - np.abs(x), height / 2 - np.abs(y)  # distance to the nearer side edges
        inside = dx + dy >= corner * side
    elif border == "letterbox":
        inside = np.broadcast_to(np.abs(y) <= (1.0 - bars) * height / 2, (height, width))
    else:
        raise InputError(f"nuisance.border: unknown border {border!r} (choose {', '.join(BORDERS)})")
    return np.ascontiguousarray(inside, dtype=bool)


def edge_alpha(mask: np.ndarray, edge_px: float = EDGE_PX) -> np.ndarray:
    """(H, W) float32 weight of the image in each pixel: 0 outside ``mask``, rising to 1 over
    ``edge_px`` pixels inside it (the soft edge of a real border; pixels outside stay dark)."""
    if mask.all():
        return np.ones(mask.shape, np.float32)
    d = cv2.distanceTransform(mask.astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    return np.clip((d - 0.5) / np.float32(edge_px), 0.0, 1.0).astype(np.float32)


def apply_border(rgb: np.ndarray, alpha: np.ndarray, level: float, rng: np.random.Generator) -> np.ndarray:
    """Blend ``rgb`` into a near-black border: grey ``level`` (0..255) with noise of std
    :data:`BORDER_NOISE`, clipped to [0, level + 4], weighted by ``alpha`` (:func:`edge_alpha`)."""
    h, w = alpha.shape
    dark = np.float32(level) + np.float32(BORDER_NOISE) * rng.standard_normal((h, w, 3), dtype=np.float32)
    dark = np.clip(dark, 0.0, level + 4.0)
    a = alpha[..., None]
    out = rgb.astype(np.float32) * a + dark * (1.0 - a)
    return np.clip(np.rint(out), 0, 255).astype(np.uint8)


# ---------------------------------------------------------------------- blur and exposure
def line_kernel(length_px: float, angle_rad: float) -> np.ndarray:
    """Normalised float32 kernel of an anti-aliased line ``length_px`` long at ``angle_rad``
    (0 = along the image x axis), centred: the blur of a camera moving in a straight line."""
    n = max(3, int(math.ceil(length_px)) | 1)
    c = (n - 1) / 2
    half = 0.5 * max(length_px - 1.0, 0.0)
    dx, dy = half * math.cos(angle_rad), half * math.sin(angle_rad)
    canvas = np.zeros((n, n), np.uint8)
    p0 = (round((c - dx) * 16), round((c - dy) * 16))
    p1 = (round((c + dx) * 16), round((c + dy) * 16))
    cv2.line(canvas, p0, p1, 255, 1, cv2.LINE_AA, shift=4)
    k = canvas.astype(np.float32)
    return k / k.sum()


def disc_kernel(radius_px: float) -> np.ndarray:
    """Normalised float32 kernel of an anti-aliased filled disc of ``radius_px`` (defocus)."""
    n = 2 * int(math.ceil(radius_px)) + 1
    c = (n - 1) // 2
    canvas = np.zeros((n, n), np.uint8)
    cv2.circle(canvas, (c * 16, c * 16), round(radius_px * 16), 255, -1, cv2.LINE_AA, shift=4)
    k = canvas.astype(np.float32)
    return k / k.sum()


def _filter(rgb: np.ndarray, kernel: np.ndarray) -> np.ndarray:
    return cv2.filter2D(rgb, -1, kernel, borderType=cv2.BORDER_REFLECT_101)


def motion_blur(rgb: np.ndarray, length_px: float, angle_rad: float) -> np.ndarray:
    """``rgb`` blurred along a line ``length_px`` long in direction ``angle_rad``."""
    return _filter(rgb, line_kernel(length_px, angle_rad))


def defocus(rgb: np.ndarray, radius_px: float) -> np.ndarray:
    """``rgb`` blurred by a disc of ``radius_px`` (out of focus)."""
    return _filter(rgb, disc_kernel(radius_px))


def wash_out(rgb: np.ndarray, strength: float) -> np.ndarray:
    """Over-exposure: gain 1 + 2.5 ``strength``, lift 45 ``strength`` grey levels, colour
    desaturated by 0.3 ``strength``; at 0.8 most mucosa saturates to near white."""
    x = rgb.astype(np.float32) * np.float32(1.0 + 2.5 * strength) + np.float32(45.0 * strength)
    grey = x.mean(axis=2, keepdims=True)
    y = grey + np.float32(1.0 - 0.3 * strength) * (x - grey)
    return np.clip(np.rint(y), 0, 255).astype(np.uint8)


def jpeg_roundtrip(rgb: np.ndarray, quality: int) -> np.ndarray:
    """``rgb`` encoded as JPEG at ``quality`` (1..100) and decoded again (a re-encoded copy)."""
    ok, buf = cv2.imencode(".jpg", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise RuntimeError("nuisance.repeat: JPEG encoding failed")
    return cv2.cvtColor(cv2.imdecode(buf, cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)


# ---------------------------------------------------------------------- burned-in overlay
def clock_text(seconds: int) -> str:
    """``HH:MM:SS`` of ``seconds`` (wrapping at 24 h)."""
    s = int(seconds) % 86400
    return f"{s // 3600:02d}:{s % 3600 // 60:02d}:{s % 60:02d}"


@dataclass(frozen=True)
class _Layout:
    """Where the overlay goes in a frame (pixels); fixed for a frame size."""

    scale: float  # Hershey font scale
    thickness: int
    label_org: tuple[int, int]  # bottom-left of the label (top-left corner of the frame)
    clock_org: tuple[int, int]  # bottom-left of the clock (bottom-left corner)
    icon_centre: tuple[int, int]  # filled disc (top-right corner)
    icon_radius: int


def _layout(width: int, height: int) -> _Layout:
    side = min(width, height)
    scale = max(0.25, side / 640.0)
    thickness = 1 + side // 700
    margin = max(2, round(0.025 * side))
    (_, text_h), baseline = cv2.getTextSize("0", cv2.FONT_HERSHEY_SIMPLEX, scale, thickness)
    r = max(2, round(0.02 * side))
    return _Layout(scale, thickness, (margin, margin + text_h), (margin, height - margin - baseline),
                   (width - margin - r, margin + r), r)


def overlay_alpha(width: int, height: int, label: str, clock: str) -> tuple[np.ndarray, np.ndarray]:
    """Coverage (H, W) uint8 (0 or 255: crisp, not anti-aliased, like a video processor's
    characters) of the burned-in text and icon, and of their 1-px drop shadow: ``label`` at the
    top left, ``clock`` at the bottom left, a filled disc at the top right. The same arguments
    always give the same pixels (the overlay does not move with the scene)."""
    lay = _layout(width, height)
    text = np.zeros((height, width), np.uint8)
    font = cv2.FONT_HERSHEY_SIMPLEX
    if label:
        cv2.putText(text, label, lay.label_org, font, lay.scale, 255, lay.thickness, cv2.LINE_8)
    cv2.putText(text, clock, lay.clock_org, font, lay.scale, 255, lay.thickness, cv2.LINE_8)
    cv2.circle(text, lay.icon_centre, lay.icon_radius, 255, -1, cv2.LINE_8)
    shadow = np.zeros_like(text)
    shadow[1:, 1:] = text[:-1, :-1]
    shadow[text > 0] = 0
    return text, shadow


def burn_in(rgb: np.ndarray, text: np.ndarray, shadow: np.ndarray) -> np.ndarray:
    """``rgb`` with the overlay of :func:`overlay_alpha` drawn over it (light grey text on a
    dark shadow); pixels of full coverage become exactly :data:`OVERLAY_GREY`."""
    out = rgb.astype(np.float32)
    for alpha, grey in ((shadow, SHADOW_GREY), (text, OVERLAY_GREY)):
        a = (alpha.astype(np.float32) / 255.0)[..., None]
        out = out * (1.0 - a) + np.float32(grey) * a
    return np.clip(np.rint(out), 0, 255).astype(np.uint8)


# ---------------------------------------------------------------------- a sequence's frames
@dataclass(frozen=True)
class NuisanceFrame:
    """One output frame: ``rgb`` (H, W, 3) uint8, ``depth`` (H, W) float32 metres (0 outside the
    tissue mask), ``names`` its nuisances (in the order of :data:`NAMES`), ``source`` the index
    of the rendered frame whose pose and depth it carries (an earlier one for a repeat)."""

    rgb: np.ndarray
    depth: np.ndarray
    names: tuple[str, ...]
    source: int


def _ordered(names: set[str]) -> tuple[str, ...]:
    return tuple(n for n in NAMES if n in names)


class NuisanceChain:
    """Applies :class:`NuisanceParams` to the frames of one sequence, in frame order.

    ``width`` x ``height`` pixels, ``fps`` frames per second of video time (the clock),
    ``seed`` the sequence seed. Frame ``i`` draws from ``stream(seed, NUISANCE_STREAM, i)``
    four uniforms (motion blur, defocus, wash-out, repeat: the frame gets a nuisance when its
    uniform is below the share) and the blur direction, then the border's noise.
    """

    def __init__(self, params: NuisanceParams, width: int, height: int, fps: float, seed: int) -> None:
        self.p, self.width, self.height, self.fps, self.seed = params, width, height, fps, seed
        p = params
        self.mask = tissue_mask(width, height, p.border, p.border_scale, p.border_corner, p.border_bars)
        self.alpha = edge_alpha(self.mask) if p.border != "none" else None
        self.clock_start = int(stream(seed, NUISANCE_STREAM).integers(7 * 3600, 19 * 3600))  # s after midnight
        self._prev: NuisanceFrame | None = None
        self._next = 0
        self._overlay: tuple[str, tuple[np.ndarray, np.ndarray]] | None = None

    def clock(self, i: int) -> str:
        """The clock burned into frame ``i``: the start time plus whole seconds of video time."""
        return clock_text(self.clock_start + math.floor(i / self.fps + 1e-9))

    def overlay(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        """:func:`overlay_alpha` of frame ``i`` (cached while the clock shows the same second)."""
        clock = self.clock(i)
        if self._overlay is None or self._overlay[0] != clock:
            self._overlay = (clock, overlay_alpha(self.width, self.height, self.p.overlay_text, clock))
        return self._overlay[1]

    def apply(self, i: int, rgb: np.ndarray, depth: np.ndarray) -> NuisanceFrame:
        """Frame ``i`` (rendered ``rgb`` uint8 and ``depth`` metres) with its nuisances; frames
        must come in order 0, 1, 2, ..."""
        if i != self._next:
            raise ValueError(f"nuisances: frame {i} given after frame {self._next - 1} (frames must come in order)")
        self._next = i + 1
        p = self.p
        rng = stream(self.seed, NUISANCE_STREAM, i)
        u = rng.random(4)
        angle = float(rng.uniform(0.0, math.pi))
        if self._prev is not None and u[3] < p.repeat_share:
            prev = self._prev
            frame = NuisanceFrame(jpeg_roundtrip(prev.rgb, p.repeat_quality), prev.depth,
                                  _ordered({*prev.names, "repeat"}), prev.source)
        else:
            frame = self._fresh(i, rgb, depth, u, angle, rng)
        self._prev = frame
        return frame

    def _fresh(self, i: int, rgb: np.ndarray, depth: np.ndarray, u: np.ndarray, angle: float,
               rng: np.random.Generator) -> NuisanceFrame:
        p = self.p
        names: set[str] = set()
        img = rgb
        if u[1] < p.defocus_share:
            img = defocus(img, p.defocus_px)
            names.add("defocus")
        if u[0] < p.motion_blur_share:
            img = motion_blur(img, p.motion_blur_px, angle)
            names.add("motion_blur")
        if u[2] < p.washed_out_share:
            img = wash_out(img, p.washed_out_strength)
            names.add("washed_out")
        if self.alpha is not None:
            img = apply_border(img, self.alpha, p.border_level, rng)
            depth = np.where(self.mask, depth, np.float32(0.0)).astype(depth.dtype)
            names.add("border")
        if p.overlay:
            img = burn_in(img, *self.overlay(i))
            names.add("overlay")
        return NuisanceFrame(img, depth, _ordered(names), i)

    # ------------------------------------------------------------------ truth files
    def write_truth(self, root: str | Path, names: dict[int, tuple[str, ...]]) -> None:
        """``tissue_mask.png`` (uint8, 255 = tissue; only with a border) and ``nuisances.json``
        (frame index -> list of names) into the sequence folder ``root``."""
        root = Path(root)
        if self.alpha is not None and not cv2.imwrite(str(root / "tissue_mask.png"), self.mask.astype(np.uint8) * 255):
            raise OSError(f"could not write {root / 'tissue_mask.png'}")
        lines = [f'  "{i}": {json.dumps(list(names[i]))}' for i in sorted(names)]
        (root / "nuisances.json").write_text("{\n" + ",\n".join(lines) + "\n}\n")


def read_nuisances(root: str | Path) -> dict[int, list[str]]:
    """A sequence's ``nuisances.json`` as frame index -> names; empty when the file is absent."""
    path = Path(root) / "nuisances.json"
    if not path.is_file():
        return {}
    return {int(k): list(v) for k, v in json.loads(path.read_text()).items()}
