"""Domain randomisation: a seeded sampler of a simulated sequence's look for training data.

:func:`sample_look` draws one value per field of :class:`LookRanges` (uniform in a range, or a
choice) and returns simulator ``--set`` items, ``group.field=value``::

    items = sample_look(7)            # ('appearance.hue=12.51', ..., 'recording.noise=0.213', ...)
    args = set_args(items)            # ('--set', 'appearance.hue=12.51', '--set', ...)

Groups: ``appearance.`` / ``colon.`` / ``nuisance.`` are :mod:`datamodules.synthetic.params`
fields; ``recording.`` are :class:`datamodules.synthetic.recording.RecordingParams` fields
(``SimParams.recording``: the simulator applies them; :func:`split_items` separates them for a
caller that applies them itself with
:func:`datamodules.synthetic.recording.recording_from_items`). Each field draws from its own
stream, ``stream(seed, LOOK_STREAM, crc32(name))``, so the same seed gives the same items and
narrowing one range leaves the other fields' values as they were. Units are those of the target
fields (degrees, fractions, metres, pixels).

The defaults cover real colonoscopy: pink-red to orange mucosa, dry to wet, vessels faint to
clear, warm light of varied strength and fall-off, bordered or full-frame video, some blur,
compressed and noisy. They were tuned against the C3VD phantom clip
(benchmarks/protocols/sim_realism.py: each frame's distance to the nearest real frame) without
narrowing onto its single look: mucosa saturation 0.5..0.8 and albedo 0.55..0.85 (paler and
over-bright looks were far from every real frame), light power 0.6..1, extra fall-off up to 0.8,
wetness up to 0.35 (with the added highlights on top); hue, vessels, folds and the other
recording effects keep their wide ranges.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass, fields

from c3f_core.errors import InputError
from datamodules.synthetic.noise import stream

__all__ = ["LOOK_STREAM", "TARGETS", "LookRanges", "sample_look", "set_args", "split_items"]

#: random stream of the look sampler (noise.py 1..4, nuisances 5, recording 6)
LOOK_STREAM = 7
Range = tuple[float, float]


@dataclass(frozen=True)
class LookRanges:
    """Ranges ``(low, high)`` sampled uniformly (integers inclusive) and choices of one look; a
    range with low == high fixes the value. Units as the target field (see :data:`TARGETS`)."""

    hue: Range = (4.0, 20.0)  #: mucosa hue, degrees (0 red, 20 orange)
    saturation: Range = (0.5, 0.8)  #: mucosa HSV saturation
    value: Range = (0.55, 0.85)  #: mucosa albedo brightness
    wetness: Range = (0.05, 0.35)  #: specular strength and sharpness
    vessel_size: Range = (0.2, 0.9)  #: 0..1 (largest vessel 0.15 + 0.6 x size mm)
    vessel_opacity: Range = (0.05, 0.45)  #: vessel contrast
    vessel_density: Range = (0.3, 2.0)  #: relative number of vessel trees
    light_angle: Range = (110.0, 170.0)  #: full cone angle of the light, degrees
    light_intensity: Range = (0.6, 1.0)  #: relative light power
    auto_exposure: Range = (0.6, 1.0)  #: 0 fixed .. 1 automatic exposure
    micro_relief: Range = (0.1, 0.5)  #: fine bump map strength
    vignette: Range = (0.3, 0.9)  #: the renderer's vignette
    bloom: Range = (0.0, 0.5)  #: glow around highlights
    grain: Range = (0.0, 2.0)  #: the renderer's grain (std 0.01 grain of full range)
    fold_height: Range = (0.28, 0.48)  #: haustral fold height, fraction of the radius
    fold_spacing: Range = (0.025, 0.05)  #: mean distance between folds, m
    #: scope border shapes drawn with equal odds when a frame gets a border
    borders: tuple[str, ...] = ("circle", "octagon", "cut_corners", "letterbox")
    border_probability: float = 0.7  #: probability that the sequence has a border
    border_scale: Range = (0.95, 1.15)  #: circle / octagon size over the smaller side
    overlay_probability: float = 0.3  #: probability of burned-in text and clock
    motion_blur_share: Range = (0.0, 0.1)  #: share of motion-blurred frames
    defocus_share: Range = (0.0, 0.08)  #: share of defocused frames
    washed_out_share: Range = (0.0, 0.03)  #: share of over-exposed frames
    gain_r: Range = (0.95, 1.2)  #: recording: red gain (warm lamp)
    gain_g: Range = (0.92, 1.02)  #: recording: green gain
    gain_b: Range = (0.7, 1.0)  #: recording: blue gain
    gain_jitter: Range = (0.0, 0.03)  #: recording: per-frame white balance wobble
    falloff: Range = (0.0, 0.8)  #: recording: extra radial fall-off
    uneven: Range = (0.0, 0.6)  #: recording: off-centre light
    noise: Range = (0.03, 0.3)  #: recording: sensor noise level
    noise_chroma: Range = (0.1, 0.5)  #: recording: chroma share of the noise
    noise_grain_px: Range = (0.3, 1.2)  #: recording: noise correlation, px
    jpeg_share: Range = (0.0, 1.0)  #: recording: JPEG re-encoded frames
    jpeg_quality: Range = (40, 95)  #: recording: JPEG quality range to draw min and max from
    video_probability: float = 0.5  #: recording: probability of the mp4v round trip
    video_scale: Range = (0.5, 1.0)  #: recording: encoded size over the frame size
    interlace_share: Range = (0.0, 0.1)  #: recording: interlaced frames
    fluid_share: Range = (0.0, 0.3)  #: recording: blocks with fluid
    fluid_hue: Range = (20.0, 90.0)  #: recording: fluid colour, degrees (yellow-brown to green)
    bubbles_share: Range = (0.0, 0.25)  #: recording: blocks with bubbles
    specular_share: Range = (0.05, 0.4)  #: recording: blocks with extra highlights
    specular_count: Range = (1, 6)  #: recording: mean number of extra highlights

    def __post_init__(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            if f.name.endswith("probability"):
                if not 0.0 <= v <= 1.0:
                    raise InputError(f"look.{f.name}: must be in [0, 1], got {v!r}")
            elif f.name == "borders":
                from datamodules.synthetic.params import BORDERS

                if not v or any(b not in BORDERS for b in v):
                    raise InputError(f"look.borders: choose from {', '.join(BORDERS)}, got {v!r}")
            elif not (isinstance(v, tuple) and len(v) == 2 and v[0] <= v[1]):
                raise InputError(f"look.{f.name}: must be a (low, high) pair with low <= high, got {v!r}")


#: LookRanges field -> simulator parameter it sets (fields not listed are handled in sample_look)
TARGETS = {
    **{k: f"appearance.{k}" for k in ("hue", "saturation", "value", "wetness", "vessel_size", "vessel_opacity",
                                      "vessel_density", "light_angle", "light_intensity", "auto_exposure",
                                      "micro_relief", "vignette", "bloom", "grain")},
    "fold_height": "colon.fold_height", "fold_spacing": "colon.fold_spacing",
    "motion_blur_share": "nuisance.motion_blur_share", "defocus_share": "nuisance.defocus_share",
    "washed_out_share": "nuisance.washed_out_share",
    **{k: f"recording.{k}" for k in ("gain_r", "gain_g", "gain_b", "gain_jitter", "falloff", "uneven", "noise",
                                     "noise_chroma", "noise_grain_px", "jpeg_share", "interlace_share",
                                     "fluid_share", "fluid_hue", "bubbles_share", "specular_share",
                                     "specular_count")},
}
_INTEGER = {"specular_count", "jpeg_quality"}


def _fmt(v: object) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return f"{v:.4g}"
    return str(v)


def sample_look(seed: int, ranges: LookRanges | None = None) -> tuple[str, ...]:
    """One look: ``group.field=value`` items for the simulator's ``--set`` (module docstring);
    the same ``seed`` gives the same items. Items are in a fixed order: appearance, colon,
    nuisance, recording."""
    r = ranges if ranges is not None else LookRanges()

    def rng(name: str):
        return stream(seed, LOOK_STREAM, zlib.crc32(name.encode()))

    def draw(name: str) -> float | int:
        lo, hi = getattr(r, name)
        if name in _INTEGER:
            return int(rng(name).integers(int(lo), int(hi) + 1))
        return float(rng(name).uniform(lo, hi)) if hi > lo else float(lo)

    values = {TARGETS[name]: draw(name) for name in TARGETS}
    if rng("border").random() < r.border_probability:
        values["nuisance.border"] = r.borders[int(rng("borders").integers(0, len(r.borders)))]
        values["nuisance.border_scale"] = draw("border_scale")
    values["nuisance.overlay"] = bool(rng("overlay").random() < r.overlay_probability)
    q = sorted(int(rng(f"jpeg_quality{k}").integers(int(r.jpeg_quality[0]), int(r.jpeg_quality[1]) + 1))
               for k in (0, 1))
    values["recording.jpeg_quality_min"], values["recording.jpeg_quality_max"] = q
    if rng("video").random() < r.video_probability:
        values["recording.video"] = "mp4v"
        values["recording.video_scale"] = draw("video_scale")
    order = ("appearance.", "colon.", "nuisance.", "recording.")
    keys = sorted(values, key=lambda k: (order.index(k[: k.index(".") + 1]), k))
    return tuple(f"{k}={_fmt(values[k])}" for k in keys)


def split_items(items: tuple[str, ...] | list[str]) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """``items`` split into (those the simulator reads now, the ``recording.`` ones)."""
    rec = tuple(i for i in items if i.startswith("recording."))
    return tuple(i for i in items if not i.startswith("recording.")), rec


def set_args(items: tuple[str, ...] | list[str]) -> tuple[str, ...]:
    """``('--set', item, '--set', item, ...)`` for a command line."""
    return tuple(a for item in items for a in ("--set", item))
