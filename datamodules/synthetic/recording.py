"""Effects of a real colonoscope recording that the renderer lacks, on uint8 RGB frames.

The simulator's frames are clean and uniform; a real recording adds, per frame and in this
order (what is in the scene first, then the light, the sensor, the video processor, the
recorder):

1. ``fluid``: translucent tinted fluid patches (smooth, slightly refracting);
2. ``bubbles``: clusters of bubbles (bright thin rim, specular dot, see-through inside);
3. ``specular``: extra saturated highlight blobs and streaks, elongated along the folds;
4. ``light``: white balance (a gain per channel, warm or cool lamp), an extra radial fall-off
   and off-centre (uneven) illumination, in linear light;
5. ``noise``: sensor noise: signal-dependent shot noise plus read noise in linear light,
   optionally chroma noise and spatially correlated grain;
6. ``interlace``: the odd field shifted by a few pixels (comb artefacts of motion);
7. ``jpeg``: a JPEG round trip at a quality drawn per frame;

and over the whole sequence 8. ``video``: an MPEG-4 Part 2 (``mp4v``) encode-decode round trip
through ``cv2.VideoWriter`` / ``cv2.VideoCapture`` (:func:`video_roundtrip`).

Everything is image-only: no function here takes or returns depth or poses, so a sequence's
geometry is exactly as rendered. Fluid, bubbles and highlights come with masks of the pixels
they changed (:class:`RecordingFrame`), so that training can leave them out of its losses.

Randomness: :func:`datamodules.synthetic.noise.stream` with stream number
:data:`RECORDING_STREAM` (after GEOMETRY .. FRAME = 1..4 of noise.py and the nuisances' 5):
``(RECORDING_STREAM, FRAME_KEY, i, effect)`` per frame ``i``, ``(RECORDING_STREAM, BLOCK_KEY, b,
effect)`` per block ``b = i // persist_frames`` of frames that share one layout of fluid, bubbles
and highlights (drifting a little from frame to frame), ``(RECORDING_STREAM, SEQUENCE_KEY)`` for
the direction of uneven light. A frame's effects therefore depend only on the seed, its index
and its own pixels, not on the number of frames or on the other effects' settings; the video
codec encodes fixed chunks of ``video_chunk`` frames (frames ``c * chunk`` .. ``(c + 1) * chunk -
1``) separately, without B-frames, so a frame depends only on the earlier frames of its chunk.

Video codecs: OpenCV's FFmpeg back end here encodes ``mp4v`` (MPEG-4 Part 2) but not H.264
(``avc1`` needs an encoder this build lacks; ffmpeg and PyAV are not installed), and it fixes
the bit rate at about 1 bit per pixel per frame with no option to change it
(``VIDEOWRITER_PROP_QUALITY`` is refused, ``OPENCV_FFMPEG_WRITER_OPTIONS`` is ignored). The rate
knob is therefore ``video_scale``: the frames are encoded at that fraction of their size (about
``video_scale**2`` bits per original pixel per frame) and scaled back up, the way a recorder of
lower resolution than the display loses detail. :func:`video_codecs` says what this machine
can encode.

Conventions: frames are (H, W, 3) uint8 RGB; sizes are in pixels of the frame when the field
says ``_px``, else fractions of the frame's smaller side; grey levels 0..255; linear light is
``(x / 255) ** 2.2`` (the renderer's gamma).
"""

from __future__ import annotations

import math
import tempfile
from dataclasses import dataclass, fields
from functools import cache
from pathlib import Path

import cv2
import numpy as np

from c3f_core.errors import InputError
from datamodules.synthetic.noise import stream

__all__ = ["CODEC_EFFECTS", "EFFECTS", "RECORDING_STREAM", "SCENE_EFFECTS", "VIDEO_CODECS", "RecordingChain",
           "RecordingFrame", "RecordingParams",
           "bubble_layer", "fluid_layer", "highlight_layer", "illumination", "interlace", "jpeg", "light",
           "recording_from_items", "sensor_noise", "to_linear", "to_srgb", "video_codecs", "video_roundtrip"]

#: random stream of the recording effects (noise.py: 1..4, nuisances.py: 5)
RECORDING_STREAM = 6
FRAME_KEY, BLOCK_KEY, SEQUENCE_KEY = 0, 1, 2  # second key of the streams (module docstring)
#: the effects' names, in the order they are applied
EFFECTS = ("fluid", "bubbles", "specular", "light", "noise", "interlace", "jpeg", "video")
#: what the scene, the light and the sensor add (the simulator applies them before its nuisances)
SCENE_EFFECTS = EFFECTS[:6]
#: what the recorder adds to the processor's output (after the nuisances' border and overlay)
CODEC_EFFECTS = ("jpeg", "video")
_FX = {name: k for k, name in enumerate(EFFECTS)}  # third / fourth key: one sub-stream per effect
VIDEO_CODECS = ("none", "mp4v", "avc1")
GAMMA = 2.2


# ---------------------------------------------------------------------- parameters
@dataclass(frozen=True)
class RecordingParams:
    """What a real recording adds to the rendered frames (``SimParams.recording``, ``--set
    recording.FIELD=VALUE``); all off by default, and then the frames stay exactly as rendered. Shares are the expected
    fraction of frames (fluid, bubbles, highlights: of blocks of ``persist_frames`` frames), 0..1."""

    #: linear-light gain of the red channel (lamp colour and white balance: > 1 warm), 0.5..2
    gain_r: float = 1.0
    #: linear-light gain of the green channel, 0.5..2
    gain_g: float = 1.0
    #: linear-light gain of the blue channel (< 1 warm, > 1 cool), 0.5..2
    gain_b: float = 1.0
    #: std of each channel's per-frame log gain (automatic white balance wobble), 0..0.2
    gain_jitter: float = 0.0
    #: extra radial fall-off of the light, 0..2: linear light x exp(-2 falloff r^2), r = distance
    #: from the light's centre over the frame's half diagonal (1: corners at 14 %); 0 = off
    falloff: float = 0.0
    #: off-centre illumination, 0..1: the fall-off's centre moves 0.3 uneven half diagonals along a
    #: direction fixed per sequence and the light tilts by exp(uneven (u - 0.5)), u = position
    #: along that direction in half diagonals; 0 = off
    uneven: float = 0.0
    #: sensor noise level, 0..1 (1: a noisy, dim scope): in linear light, std = noise x
    #: sqrt(x / 400 + 0.006^2) (shot + read noise; 1: 5 % of full scale at white, ~6 grey levels
    #: at white and ~11 in the dark after gamma); 0 = off
    noise: float = 0.0
    #: share of the noise that is independent per channel (chroma noise), 0..1; the rest is common
    noise_chroma: float = 0.3
    #: Gaussian sigma of the noise's spatial correlation (demosaicing, denoising), 0..3 px; 0 = white
    noise_grain_px: float = 0.0
    #: frames re-encoded as JPEG, 0..1
    jpeg_share: float = 0.0
    #: lowest JPEG quality, 1..100 (each frame draws a quality in [min, max])
    jpeg_quality_min: int = 50
    #: highest JPEG quality, 1..100
    jpeg_quality_max: int = 90
    #: sequence-level video round trip: none, mp4v (MPEG-4 Part 2) or avc1 (H.264, where this
    #: OpenCV can encode it; :func:`video_codecs`)
    video: str = "none"
    #: frames are encoded at this fraction of their size (~ video_scale^2 bits per pixel), 0.25..1
    video_scale: float = 1.0
    #: frames per separately encoded chunk (a group of pictures), 1..300
    video_chunk: int = 12
    #: frames whose odd field (rows 1, 3, ...) is shifted (interlacing under motion), 0..1
    interlace_share: float = 0.0
    #: largest shift of the odd field, 0.5..20 px (each frame: 0.3..1 of it, random direction)
    interlace_px: float = 2.0
    #: frames that share one layout of fluid, bubbles and highlights (drifting slowly), 1..1000
    persist_frames: int = 10
    #: blocks with translucent fluid patches, 0..1
    fluid_share: float = 0.0
    #: mean share of the frame the fluid covers, 0.01..0.8 (each block: 0.5..1.5 of it)
    fluid_cover: float = 0.15
    #: opacity of the fluid (absorption of its tint and scattering), 0..1
    fluid_opacity: float = 0.6
    #: hue of the light the fluid lets through, 0..360 degrees (45: yellow-brown, 90: greenish)
    fluid_hue: float = 45.0
    #: refraction at the fluid's edges: largest displacement, 0..0.1 of the smaller side
    fluid_warp: float = 0.01
    #: blocks with bubbles, 0..1
    bubbles_share: float = 0.0
    #: mean number of bubbles of a block, 1..200 (in one or two clusters)
    bubbles_count: int = 8
    #: mean bubble radius, 0.002..0.2 of the smaller side (log-normal spread)
    bubbles_size: float = 0.03
    #: blocks with extra specular highlights, 0..1
    specular_share: float = 0.0
    #: mean number of extra highlights of a block, 1..100
    specular_count: int = 6
    #: mean half length of a highlight, 0.002..0.2 of the smaller side (log-normal spread)
    specular_size: float = 0.025
    #: largest ratio of a highlight's length to its width, 1..10 (streaks along the folds)
    specular_elongation: float = 4.0

    def __post_init__(self) -> None:
        ranges = {"gain_r": (0.5, 2.0), "gain_g": (0.5, 2.0), "gain_b": (0.5, 2.0), "gain_jitter": (0.0, 0.2),
                  "falloff": (0.0, 2.0), "uneven": (0.0, 1.0), "noise": (0.0, 1.0), "noise_chroma": (0.0, 1.0),
                  "noise_grain_px": (0.0, 3.0), "jpeg_share": (0.0, 1.0), "jpeg_quality_min": (1, 100),
                  "jpeg_quality_max": (1, 100), "video_scale": (0.25, 1.0), "video_chunk": (1, 300),
                  "interlace_share": (0.0, 1.0), "interlace_px": (0.5, 20.0), "persist_frames": (1, 1000),
                  "fluid_share": (0.0, 1.0), "fluid_cover": (0.01, 0.8), "fluid_opacity": (0.0, 1.0),
                  "fluid_hue": (0.0, 360.0), "fluid_warp": (0.0, 0.1), "bubbles_share": (0.0, 1.0),
                  "bubbles_count": (1, 200), "bubbles_size": (0.002, 0.2), "specular_share": (0.0, 1.0),
                  "specular_count": (1, 100), "specular_size": (0.002, 0.2), "specular_elongation": (1.0, 10.0)}
        for f in fields(self):
            v = getattr(self, f.name)
            if f.name == "video":
                if v not in VIDEO_CODECS:
                    raise InputError(f"recording.video: unknown codec {v!r} (choose {', '.join(VIDEO_CODECS)})")
                continue
            lo, hi = ranges[f.name]
            integer = isinstance(lo, int)
            ok_type = (isinstance(v, int) if integer else isinstance(v, (int, float))) and not isinstance(v, bool)
            if not ok_type or not math.isfinite(v) or not lo <= v <= hi:
                kind = "an integer" if integer else "a number"
                raise InputError(f"recording.{f.name}: must be {kind} in [{lo}, {hi}], got {v!r}")
        if self.jpeg_quality_min > self.jpeg_quality_max:
            raise InputError(f"recording.jpeg_quality_min: {self.jpeg_quality_min} is above jpeg_quality_max"
                             f" {self.jpeg_quality_max}")

    def active(self) -> bool:
        """True when some effect is on (otherwise :class:`RecordingChain` returns the frames as given)."""
        return bool(self.per_frame_effects()) or self.video != "none"

    def per_frame_effects(self) -> tuple[str, ...]:
        """The names of the per-frame effects that are on, in the order of :data:`EFFECTS`."""
        on = {"fluid": self.fluid_share > 0, "bubbles": self.bubbles_share > 0, "specular": self.specular_share > 0,
              "light": (self.gain_r, self.gain_g, self.gain_b) != (1.0, 1.0, 1.0) or self.gain_jitter > 0
              or self.falloff > 0 or self.uneven > 0,
              "noise": self.noise > 0, "interlace": self.interlace_share > 0, "jpeg": self.jpeg_share > 0}
        return tuple(n for n in EFFECTS if on.get(n, False))


def recording_from_items(items: dict[str, object] | list[str] | tuple[str, ...],
                         base: RecordingParams | None = None) -> RecordingParams:
    """``base`` (default: all off) with fields set from ``{"noise": "0.3"}`` or from command-line
    items ``"recording.noise=0.3"`` (the ``recording.`` prefix optional; items of other groups
    are ignored); strings are converted to the field types. InputError naming a bad field."""
    from dataclasses import replace

    from c3f_core.settings import convert_value, field_types

    if not isinstance(items, dict):
        pairs: dict[str, object] = {}
        for item in items:
            if "=" not in item:
                raise InputError(f"--set: expected KEY=VALUE, got {item!r}")
            key, value = item.split("=", 1)
            key = key.strip()
            if "." in key and not key.startswith("recording."):
                continue
            pairs[key.removeprefix("recording.")] = value.strip()
        items = pairs
    types = field_types(RecordingParams)
    changes = {}
    for key, value in items.items():
        key = key.removeprefix("recording.")
        if key not in types:
            raise InputError(f"unknown parameter 'recording.{key}'")
        changes[key] = convert_value(value, types[key], f"recording.{key}")
    return replace(base or RecordingParams(), **changes)


# ---------------------------------------------------------------------- colour and light
def to_linear(rgb: np.ndarray) -> np.ndarray:
    """uint8 sRGB-like frame -> float32 linear light in [0, 1] (gamma :data:`GAMMA`)."""
    return cv2.pow(rgb.astype(np.float32) * np.float32(1.0 / 255.0), GAMMA)


def to_srgb(lin: np.ndarray) -> np.ndarray:
    """float32 linear light -> uint8 frame (clipped to [0, 1] first, rounded)."""
    y = cv2.pow(np.clip(lin, 0.0, 1.0).astype(np.float32), 1.0 / GAMMA)
    return np.clip(y * 255.0 + 0.5, 0, 255).astype(np.uint8)


def illumination(width: int, height: int, falloff: float, uneven: float, direction_rad: float) -> np.ndarray:
    """(H, W) float32 multiplier of linear light: exp(-2 falloff r^2) about a centre moved 0.3
    ``uneven`` half diagonals along ``direction_rad`` (0 = +x, image y down), times
    exp(``uneven`` (u - 0.5)) with u the position along that direction, in half diagonals."""
    half = 0.5 * math.hypot(width, height)
    x = (np.arange(width, dtype=np.float32) + 0.5 - width / 2) / np.float32(half)
    y = (np.arange(height, dtype=np.float32) + 0.5 - height / 2) / np.float32(half)
    dx, dy = math.cos(direction_rad), math.sin(direction_rad)
    cx, cy = 0.3 * uneven * dx, 0.3 * uneven * dy
    r2 = (x[None, :] - cx) ** 2 + (y[:, None] - cy) ** 2
    u = x[None, :] * dx + y[:, None] * dy
    return np.exp(-2.0 * falloff * r2 + uneven * (u - 0.5)).astype(np.float32)


def light(rgb: np.ndarray, gains: tuple[float, float, float] | np.ndarray,
          field: np.ndarray | None = None) -> np.ndarray:
    """``rgb`` with linear light multiplied by the per-channel ``gains`` (R, G, B) and the (H, W)
    ``field`` (:func:`illumination`; None = uniform)."""
    lin = to_linear(rgb) * np.asarray(gains, np.float32)[None, None, :]
    if field is not None:
        lin *= field[..., None]
    return to_srgb(lin)


# ---------------------------------------------------------------------- sensor
def sensor_noise(rgb: np.ndarray, level: float, chroma: float, grain_px: float,
                 rng: np.random.Generator) -> np.ndarray:
    """``rgb`` with shot and read noise in linear light: std = ``level`` sqrt(x / 400 + 0.006^2);
    a share ``chroma`` of the noise is independent per channel, the rest common to the three;
    ``grain_px`` > 0 correlates it over a Gaussian of that sigma (px), at the same std."""
    h, w = rgb.shape[:2]
    lin = to_linear(rgb)
    common = rng.standard_normal((h, w, 1), dtype=np.float32)
    per = rng.standard_normal((h, w, 3), dtype=np.float32)
    if grain_px > 0:
        k = np.float32(2.0 * math.sqrt(math.pi) * max(grain_px, 0.5))  # keeps unit std after blurring
        common = (cv2.GaussianBlur(common[..., 0], (0, 0), grain_px) * k)[..., None]
        per = cv2.GaussianBlur(per, (0, 0), grain_px) * k
    z = np.float32(math.sqrt(1.0 - chroma)) * common + np.float32(math.sqrt(chroma)) * per
    sigma = np.float32(level) * cv2.sqrt(lin * np.float32(1.0 / 400.0) + np.float32(0.006**2))
    return to_srgb(lin + sigma * z)


def interlace(rgb: np.ndarray, dx: float, dy: float) -> np.ndarray:
    """``rgb`` with its odd rows (1, 3, ...) taken from a copy shifted by (``dx``, ``dy``) px (the
    field captured half a frame interval apart); even rows unchanged."""
    m = np.float32([[1, 0, dx], [0, 1, dy]])
    shifted = cv2.warpAffine(rgb, m, (rgb.shape[1], rgb.shape[0]), flags=cv2.INTER_LINEAR,
                             borderMode=cv2.BORDER_REFLECT_101)
    out = rgb.copy()
    out[1::2] = shifted[1::2]
    return out


def _shift_mask(mask: np.ndarray, dx: float, dy: float) -> np.ndarray:
    """``mask`` plus its odd rows' pixels after :func:`interlace`'s shift (conservative)."""
    m = np.float32([[1, 0, dx], [0, 1, dy]])
    moved = cv2.warpAffine(mask.astype(np.uint8), m, mask.shape[::-1], flags=cv2.INTER_LINEAR,
                           borderMode=cv2.BORDER_REFLECT_101) > 0
    out = mask.copy()
    out[1::2] |= moved[1::2]
    return out


# ---------------------------------------------------------------------- compression
def jpeg(rgb: np.ndarray, quality: int) -> np.ndarray:
    """``rgb`` encoded as JPEG at ``quality`` (1..100) and decoded again."""
    ok, buf = cv2.imencode(".jpg", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise RuntimeError("recording.jpeg: JPEG encoding failed")
    return cv2.cvtColor(cv2.imdecode(buf, cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)


def _open_writer(path: Path, codec: str, size: tuple[int, int], fps: float) -> cv2.VideoWriter:
    return cv2.VideoWriter(str(path), cv2.CAP_FFMPEG, cv2.VideoWriter_fourcc(*codec), fps, size)


@cache
def video_codecs() -> tuple[str, ...]:
    """The codecs of :data:`VIDEO_CODECS` (besides ``none``) that this OpenCV can encode and decode."""
    out = []
    with tempfile.TemporaryDirectory() as tmp:
        for codec in VIDEO_CODECS[1:]:
            path = Path(tmp) / f"probe_{codec}.mp4"
            w = _open_writer(path, codec, (32, 32), 30.0)
            if w.isOpened():
                w.write(np.zeros((32, 32, 3), np.uint8))
            w.release()
            cap = cv2.VideoCapture(str(path))
            ok = cap.isOpened() and cap.read()[0]
            cap.release()
            if ok:
                out.append(codec)
    return tuple(out)


def _even(n: float) -> int:
    return max(16, 2 * round(n / 2))


def video_roundtrip(frames: list[np.ndarray], codec: str = "mp4v", scale: float = 1.0, chunk: int = 12,
                    fps: float = 30.0) -> list[np.ndarray]:
    """``frames`` (equal-size uint8 RGB) encoded as ``codec`` video at ``scale`` of their size in
    chunks of ``chunk`` frames (each a separate file: a frame depends only on the earlier frames of
    its chunk), decoded and scaled back; OpenCV's writer spends about 1 bit per encoded pixel."""
    if not frames:
        return []
    if codec not in video_codecs():
        raise InputError(f"recording.video: this OpenCV cannot encode {codec!r} (available: "
                         f"{', '.join(video_codecs()) or 'none'})")
    h, w = frames[0].shape[:2]
    size = (_even(w * scale), _even(h * scale))
    out: list[np.ndarray] = []
    with tempfile.TemporaryDirectory(prefix="c3f_video_") as tmp:
        for start in range(0, len(frames), chunk):
            part = frames[start:start + chunk]
            path = Path(tmp) / f"chunk_{start:06d}.mp4"
            writer = _open_writer(path, codec, size, fps)
            if not writer.isOpened():
                raise RuntimeError(f"recording.video: could not open a {codec} writer")
            for f in part:
                small = f if size == (w, h) else cv2.resize(f, size, interpolation=cv2.INTER_AREA)
                writer.write(cv2.cvtColor(small, cv2.COLOR_RGB2BGR))
            writer.release()
            cap = cv2.VideoCapture(str(path))
            for _ in part:
                ok, f = cap.read()
                if not ok:
                    cap.release()
                    raise RuntimeError(f"recording.video: {codec} decoding returned too few frames")
                f = cv2.cvtColor(f, cv2.COLOR_BGR2RGB)
                out.append(f if size == (w, h) else cv2.resize(f, (w, h), interpolation=cv2.INTER_CUBIC))
            cap.release()
    return out


# ---------------------------------------------------------------------- fluid, bubbles, highlights
def _smooth_field(rng: np.random.Generator, width: int, height: int, shift: tuple[float, float]) -> np.ndarray:
    """(H, W) float32 smooth random field (two octaves, ~1/4 and ~1/9 of the frame), translated
    by ``shift`` px; the same ``rng`` state gives the same field."""
    side = max(width, height)
    out = np.zeros((height, width), np.float32)
    xs = np.arange(width, dtype=np.float32) + 0.5 - np.float32(shift[0])
    ys = np.arange(height, dtype=np.float32) + 0.5 - np.float32(shift[1])
    for cells, weight in ((4, 1.0), (9, 0.45)):
        grid = rng.standard_normal((cells + 3, cells + 3)).astype(np.float32)
        step = side / cells
        mx = np.broadcast_to(xs[None, :] / np.float32(step) + 1.0, (height, width)).astype(np.float32)
        my = np.broadcast_to(ys[:, None] / np.float32(step) + 1.0, (height, width)).astype(np.float32)
        out += np.float32(weight) * cv2.remap(grid, mx, my, cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT_101)
    return out


def _hue_rgb(hue_deg: float, saturation: float) -> np.ndarray:
    """(3,) float32 RGB in [0, 1] of an HSV colour of value 1."""
    hsv = np.array([[[hue_deg / 2.0, saturation * 255.0, 255.0]]], np.float32)
    return (cv2.cvtColor(hsv.astype(np.uint8), cv2.COLOR_HSV2RGB)[0, 0] / 255.0).astype(np.float32)


def fluid_layer(rgb: np.ndarray, alpha: np.ndarray, opacity: float, hue_deg: float,
                warp_px: float) -> np.ndarray:
    """``rgb`` seen through fluid of coverage ``alpha`` (H, W) in [0, 1]: refracted by up to
    ``warp_px`` along the coverage's gradient, blurred (scattering), absorbing towards the colour
    of ``hue_deg`` and lifted a little (milky), with a faint sheen at the edges; exactly unchanged
    where ``alpha`` is 0."""
    h, w = alpha.shape
    scale = min(h, w) / 256.0
    gy, gx = np.gradient(cv2.GaussianBlur(alpha, (0, 0), max(1.0, 2.0 * scale)))
    g = np.sqrt(gx * gx + gy * gy)
    norm = np.float32(warp_px / max(float(g.max()), 1e-6))
    mx = (np.arange(w, dtype=np.float32)[None, :] + gx * norm).astype(np.float32)
    my = (np.arange(h, dtype=np.float32)[:, None] + gy * norm).astype(np.float32)
    seen = cv2.remap(rgb, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT_101)
    seen = cv2.GaussianBlur(seen, (0, 0), max(0.6, 1.2 * scale))
    lin = to_linear(seen)
    tint = _hue_rgb(hue_deg, 0.6)
    a = (alpha * np.float32(opacity))[..., None]
    trans = np.power(tint[None, None, :], 0.8 * a)  # Beer-Lambert: absorption grows with thickness
    milky = np.float32(0.08) * a * float(lin.mean()) * tint[None, None, :]
    sheen = (np.float32(0.25 * opacity) * (g / max(float(g.max()), 1e-6)) ** 2)[..., None]
    fluid = lin * trans + milky + sheen
    base = to_linear(rgb)
    mixed = to_srgb(base + alpha[..., None] * (fluid - base))
    return np.where((alpha > 0)[..., None], mixed, rgb)


def bubble_layer(rgb: np.ndarray, bubbles: list[tuple[float, float, float]]) -> tuple[np.ndarray, np.ndarray]:
    """``rgb`` with bubbles (centre x, y and radius r, px) drawn: a see-through, slightly magnifying
    and brightened inside, a dark inner edge, a bright thin rim and a specular dot towards the
    image centre (the light sits at the lens); returns the frame and the (H, W) bool mask of the
    pixels within r + 1.5 px of a centre (the only pixels changed)."""
    h, w = rgb.shape[:2]
    lin = to_linear(rgb)
    mask = np.zeros((h, w), bool)
    cx0, cy0 = w / 2.0, h / 2.0
    for bx, by, r in bubbles:
        reach = r + 1.5
        x0, x1 = max(0, int(bx - reach)), min(w, int(math.ceil(bx + reach)) + 1)
        y0, y1 = max(0, int(by - reach)), min(h, int(math.ceil(by + reach)) + 1)
        if x0 >= x1 or y0 >= y1:
            continue
        xs = np.arange(x0, x1, dtype=np.float32)[None, :] + 0.5
        ys = np.arange(y0, y1, dtype=np.float32)[:, None] + 0.5
        d = np.sqrt((xs - bx) ** 2 + (ys - by) ** 2)
        near = d <= reach
        patch = lin[y0:y1, x0:x1]
        # inside: the tissue behind, magnified about the centre and brightened
        mx = (bx + (xs - bx) * 0.85 - 0.5).astype(np.float32)
        my = (by + (ys - by) * 0.85 - 0.5).astype(np.float32)
        behind = cv2.remap(lin, np.broadcast_to(mx, d.shape).copy(), np.broadcast_to(my, d.shape).copy(),
                           cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT_101)
        inside = np.clip((r - d) + 0.5, 0.0, 1.0)[..., None]  # anti-aliased disc
        body = behind * 1.08 + 0.03
        width = max(0.6, 0.07 * r)
        rim = np.exp(-0.5 * ((d - (r - 0.5 * width)) / width) ** 2)[..., None]
        dark = np.exp(-0.5 * ((d - (r - 2.5 * width)) / width) ** 2)[..., None]
        toward = np.array([cx0 - bx, cy0 - by], np.float64)
        toward *= 0.35 * r / max(np.linalg.norm(toward), 1e-6)
        dot_r = max(0.7, 0.15 * r)
        dot = np.exp(-0.5 * (((xs - bx - toward[0]) ** 2 + (ys - by - toward[1]) ** 2) / dot_r**2))[..., None]
        out = patch + inside * (body - patch) * 0.6
        out = out * (1.0 - 0.35 * dark * inside)
        out = out + 0.7 * rim * (1.0 - out) + 1.5 * dot
        lin[y0:y1, x0:x1] = np.where(near[..., None], out, patch)
        mask[y0:y1, x0:x1] |= near
    out = to_srgb(lin)
    return np.where(mask[..., None], out, rgb), mask


def highlight_layer(rgb: np.ndarray, spots: list[tuple[float, float, float, float, float]]
                    ) -> tuple[np.ndarray, np.ndarray]:
    """``rgb`` with saturated specular highlights: each spot (x, y px, half length a px, half
    width b px, angle rad of the long axis) a flat-topped ellipse over a soft halo, added in linear
    light; returns the frame and the (H, W) bool mask of the pixels changed (weight above 1 %)."""
    h, w = rgb.shape[:2]
    weight = np.zeros((h, w), np.float32)
    for x, y, a, b, ang in spots:
        reach = 4.0 * a + 2.0
        x0, x1 = max(0, int(x - reach)), min(w, int(math.ceil(x + reach)) + 1)
        y0, y1 = max(0, int(y - reach)), min(h, int(math.ceil(y + reach)) + 1)
        if x0 >= x1 or y0 >= y1:
            continue
        xs = np.arange(x0, x1, dtype=np.float32)[None, :] + 0.5 - x
        ys = np.arange(y0, y1, dtype=np.float32)[:, None] + 0.5 - y
        c, s = math.cos(ang), math.sin(ang)
        u = (xs * c + ys * s) / max(a, 0.5)
        v = (-xs * s + ys * c) / max(b, 0.5)
        q = u * u + v * v
        core = np.exp(-(q**2))  # flat top, sharp edge
        halo = 0.25 * np.exp(-q / 2.0)
        weight[y0:y1, x0:x1] = np.maximum(weight[y0:y1, x0:x1], core + halo)
    weight[weight < 0.01] = 0.0
    mask = weight > 0
    lin = to_linear(rgb)
    out = to_srgb(lin + 2.5 * weight[..., None] * (1.0 - 0.3 * lin))
    return np.where(mask[..., None], out, rgb), mask


def _lumen_centre(rgb: np.ndarray, tissue: np.ndarray | None) -> tuple[float, float]:
    """Pixel (x, y) of the darkest region of the heavily blurred luminance (the lumen)."""
    grey = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY).astype(np.float32)
    if tissue is not None:
        grey = np.where(tissue, grey, 255.0).astype(np.float32)
    blur = cv2.GaussianBlur(grey, (0, 0), 0.12 * min(grey.shape))
    y, x = np.unravel_index(int(np.argmin(blur)), blur.shape)
    return float(x) + 0.5, float(y) + 0.5


def _inside(layer: tuple[np.ndarray, np.ndarray], before: np.ndarray,
            tissue: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """A layer's frame and mask kept to ``tissue`` (the pixels outside it as ``before``)."""
    img, mask = layer
    if tissue is None:
        return img, mask
    return np.where(tissue[..., None], img, before), mask & tissue


# ---------------------------------------------------------------------- the chain
@dataclass(frozen=True)
class RecordingFrame:
    """One output frame: ``rgb`` (H, W, 3) uint8; ``covered`` (H, W) bool, pixels changed by fluid
    or bubbles; ``specular`` (H, W) bool, pixels of the extra highlights (both widened by
    interlacing); ``names`` the effects applied, in the order of :data:`EFFECTS`."""

    rgb: np.ndarray
    covered: np.ndarray
    specular: np.ndarray
    names: tuple[str, ...]


class RecordingChain:
    """Applies :class:`RecordingParams` to the frames of one sequence of ``width`` x ``height`` px
    and seed ``seed``; ``fps`` only sets the video's frame rate. :meth:`apply` is per frame and
    needs no order; :meth:`apply_sequence` adds the sequence-level video round trip."""

    def __init__(self, params: RecordingParams, width: int, height: int, seed: int, fps: float = 30.0) -> None:
        if params.video != "none" and params.video not in video_codecs():
            raise InputError(f"recording.video: this OpenCV cannot encode {params.video!r} (available: "
                             f"{', '.join(video_codecs()) or 'none'})")
        self.p, self.width, self.height, self.seed, self.fps = params, width, height, seed, fps
        self.side = min(width, height)
        self.on = params.per_frame_effects()
        direction = float(stream(seed, RECORDING_STREAM, SEQUENCE_KEY).uniform(0.0, 2.0 * math.pi))
        self.field = None
        if params.falloff > 0 or params.uneven > 0:
            self.field = illumination(width, height, params.falloff, params.uneven, direction)

    def _frame_rng(self, i: int, effect: str) -> np.random.Generator:
        return stream(self.seed, RECORDING_STREAM, FRAME_KEY, i, _FX[effect])

    def _block(self, i: int, effect: str, share: float) -> tuple[np.random.Generator, int] | None:
        """The block's generator and frame ``i``'s place in its block, when the block has ``effect``."""
        b, k = divmod(i, self.p.persist_frames)
        rng = stream(self.seed, RECORDING_STREAM, BLOCK_KEY, b, _FX[effect])
        return (rng, k) if rng.random() < share else None

    def apply(self, i: int, rgb: np.ndarray, tissue: np.ndarray | None = None,
              only: tuple[str, ...] | None = None) -> RecordingFrame:
        """Frame ``i``'s per-frame effects on ``rgb`` ((H, W, 3) uint8); ``tissue`` (H, W) bool
        keeps fluid, bubbles and highlights inside the scope's border (None: everywhere); ``only``
        applies just those of the effects that are on (e.g. :data:`SCENE_EFFECTS`, then later
        ``("jpeg",)``: the same frames as all at once, since each effect has its own stream)."""
        h, w = self.height, self.width
        if rgb.shape != (h, w, 3) or rgb.dtype != np.uint8:
            raise ValueError(f"recording: frame {i} must be ({h}, {w}, 3) uint8, got {rgb.shape} {rgb.dtype}")
        p, img, names = self.p, rgb, []
        on = self.on if only is None else tuple(n for n in self.on if n in only)
        covered = np.zeros((h, w), bool)
        specular = np.zeros((h, w), bool)
        if "fluid" in on and (blk := self._block(i, "fluid", p.fluid_share)):
            alpha = self._fluid_alpha(*blk, tissue)
            if alpha.any():
                img = fluid_layer(img, alpha, p.fluid_opacity, p.fluid_hue, p.fluid_warp * self.side)
                covered |= alpha > 0
                names.append("fluid")
        if "bubbles" in on and (blk := self._block(i, "bubbles", p.bubbles_share)):
            img, m = _inside(bubble_layer(img, self._bubbles(*blk, tissue)), img, tissue)
            if m.any():
                covered |= m
                names.append("bubbles")
        if "specular" in on and (blk := self._block(i, "specular", p.specular_share)):
            img, m = _inside(highlight_layer(img, self._spots(*blk, img, tissue)), img, tissue)
            if m.any():
                specular |= m
                names.append("specular")
        if "light" in on:
            jitter = self._frame_rng(i, "light").normal(0.0, p.gain_jitter, 3) if p.gain_jitter > 0 else 0.0
            gains = np.array([p.gain_r, p.gain_g, p.gain_b]) * np.exp(jitter)
            img = light(img, gains, self.field)
            names.append("light")
        if "noise" in on:
            img = sensor_noise(img, p.noise, p.noise_chroma, p.noise_grain_px, self._frame_rng(i, "noise"))
            names.append("noise")
        if "interlace" in on:
            rng = self._frame_rng(i, "interlace")
            if rng.random() < p.interlace_share:
                shift, ang = p.interlace_px * rng.uniform(0.3, 1.0), rng.uniform(0.0, 2.0 * math.pi)
                dx, dy = shift * math.cos(ang), shift * math.sin(ang)
                img = interlace(img, dx, dy)
                covered, specular = _shift_mask(covered, dx, dy), _shift_mask(specular, dx, dy)
                names.append("interlace")
        if "jpeg" in on:
            rng = self._frame_rng(i, "jpeg")
            if rng.random() < p.jpeg_share:
                img = jpeg(img, int(rng.integers(p.jpeg_quality_min, p.jpeg_quality_max + 1)))
                names.append("jpeg")
        return RecordingFrame(img if img is not rgb else rgb.copy(), covered, specular, tuple(names))

    def apply_sequence(self, frames: list[np.ndarray], tissue: np.ndarray | None = None) -> list[RecordingFrame]:
        """Every frame's :meth:`apply` (frame index = position in ``frames``), then the video round trip."""
        out = [self.apply(i, f, tissue) for i, f in enumerate(frames)]
        if self.p.video == "none":
            return out
        coded = video_roundtrip([f.rgb for f in out], self.p.video, self.p.video_scale, self.p.video_chunk, self.fps)
        return [RecordingFrame(c, f.covered, f.specular, (*f.names, "video")) for c, f in zip(coded, out)]

    # ------------------------------------------------------------------ layouts of a block
    def _drift(self, rng: np.random.Generator, k: int) -> tuple[float, float]:
        """Translation (px) of a block's layout at its ``k``-th frame: ~0.4 % of the side per frame."""
        v = rng.normal(0.0, 0.004 * self.side, 2)
        return float(v[0] * k), float(v[1] * k)

    def _fluid_alpha(self, rng: np.random.Generator, k: int, tissue: np.ndarray | None) -> np.ndarray:
        p = self.p
        cover = float(np.clip(p.fluid_cover * rng.uniform(0.5, 1.5), 0.005, 0.95))
        shift = self._drift(rng, k)
        state = rng.bit_generator.state
        base = _smooth_field(rng, self.width, self.height, (0.0, 0.0))
        rng.bit_generator.state = state  # the same field, translated
        field = _smooth_field(rng, self.width, self.height, shift) if k else base
        thr = float(np.quantile(base, 1.0 - cover))
        edge = 0.25 * float(base.std())
        t = np.clip((field - thr) / np.float32(edge), 0.0, 1.0)
        alpha = (t * t * (3.0 - 2.0 * t)).astype(np.float32)
        if tissue is not None:
            alpha *= tissue
        return alpha

    def _bubbles(self, rng: np.random.Generator, k: int, tissue: np.ndarray | None) -> list[tuple[float, float, float]]:
        p = self.p
        shift = self._drift(rng, k)
        n = 1 + int(rng.poisson(max(p.bubbles_count - 1, 0)))
        clusters = 1 + int(rng.random() < 0.4)
        mean_r = p.bubbles_size * self.side
        centres = rng.uniform([0.1 * self.width, 0.1 * self.height], [0.9 * self.width, 0.9 * self.height],
                              (clusters, 2))
        which = rng.integers(0, clusters, n)
        radii = np.maximum(1.2, mean_r * np.exp(rng.normal(-0.08, 0.4, n)))
        offsets = rng.normal(0.0, 1.0, (n, 2)) * (2.0 * mean_r * math.sqrt(n / clusters) ** 0.5)
        out = []
        for c, r, o in zip(which, radii, offsets):
            x, y = centres[c] + o + shift
            if tissue is not None:
                xi, yi = int(np.clip(x, 0, self.width - 1)), int(np.clip(y, 0, self.height - 1))
                if not tissue[yi, xi]:
                    continue
            out.append((float(x), float(y), float(r)))
        return out

    def _spots(self, rng: np.random.Generator, k: int, img: np.ndarray,
               tissue: np.ndarray | None) -> list[tuple[float, float, float, float, float]]:
        """Highlights on bright (near, facing) tissue, their long axis across the direction to the
        lumen (along the folds, which circle it)."""
        p = self.p
        shift = self._drift(rng, k)
        n = 1 + int(rng.poisson(max(p.specular_count - 1, 0)))
        u = rng.random((n, 2))
        size = p.specular_size * self.side * np.exp(rng.normal(-0.1, 0.45, n))
        elong = rng.uniform(1.0, p.specular_elongation, n)
        jitter = rng.normal(0.0, 0.25, n)
        parts = rng.integers(1, 4, n)
        grey = cv2.resize(cv2.cvtColor(img, cv2.COLOR_RGB2GRAY), (32, 32), interpolation=cv2.INTER_AREA)
        weight = (grey.astype(np.float64) / 255.0) ** 3
        if tissue is not None:
            weight *= cv2.resize(tissue.astype(np.uint8), (32, 32), interpolation=cv2.INTER_NEAREST)
        total = weight.sum()
        if total <= 0:
            return []
        cdf = np.cumsum(weight.ravel()) / total
        cells = np.minimum(np.searchsorted(cdf, u[:, 0]), cdf.size - 1)
        lx, ly = _lumen_centre(img, tissue)
        out = []
        for j in range(n):
            cy, cx = divmod(int(cells[j]), 32)
            sub = u[j, 1]
            x = (cx + sub) * self.width / 32.0 + shift[0]
            y = (cy + (sub * 7.0) % 1.0) * self.height / 32.0 + shift[1]
            ang = math.atan2(y - ly, x - lx) + math.pi / 2 + jitter[j]
            a = float(size[j])
            b = max(0.5, a / elong[j])
            for m in range(int(parts[j])):  # a streak of one to three droplets along the axis
                t = (m - (parts[j] - 1) / 2.0) * 1.6 * a
                out.append((x + t * math.cos(ang), y + t * math.sin(ang), a * (1.0 - 0.2 * m), b, ang))
        return out
