"""Every parameter of the simulator, its validation, and the presets of the paper's eight sequences.

Units: metres for lengths, degrees for angles given by the user (converted to radians in
the code that uses them), fractions in [0, 1] for appearance strengths. All randomness
comes from ``seed`` (see :mod:`datamodules.synthetic.noise`), so a seed plus these
parameters fixes a sequence byte for byte.

The groups are frozen dataclasses that check themselves when they are made (one InputError
naming ``group.field``); :class:`SimParams` also checks what depends on two groups (the camera,
the light, the texture and the path against the colon's size). Change them with
:func:`dataclasses.replace` or :func:`c3f_core.settings.set_path` /
:func:`~c3f_core.settings.tree_from_mapping`; the command line's ``--preset`` / ``--config`` /
``--set`` / ``--print-config`` are :data:`SIM_SETTINGS` (:mod:`c3f_core.settings_cli`).

The paper's appendix table (Unity simulator sliders, mostly 0..100) is kept verbatim in
:data:`PAPER_TABLE`; :func:`paper_preset` maps those slider values to the physical
parameters below (the mapping is this project's choice and is documented next to it).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field, fields, is_dataclass
from functools import partial
from pathlib import Path
from typing import Any

from c3f_core.errors import InputError
from c3f_core.settings import convert_value, field_types, tree_from_mapping
from c3f_core.settings_cli import SettingsSpec
from datamodules.synthetic.recording import RecordingParams

PATH_KINDS = ("A", "B", "random")
LAYOUTS = ("c3f", "uts", "simcol3d", "c3vd", "colon10k")  # output layouts (c3f = the project's own, docs/datasets.md)
LAYOUT_ALIASES = {"simcol": "simcol3d"}  # earlier name
PATH_ALIASES = {"a": "A", "b": "B", "random": "random", "rp": "random"}
BORDERS = ("none", "circle", "octagon", "cut_corners", "letterbox")  # nuisance.border shapes


def _check(cond: bool, msg: str) -> None:
    if not cond:
        raise InputError(msg)


class _Group:
    """Base of the frozen parameter groups: on creation each field is converted to its type
    (:func:`c3f_core.settings.convert_value`; an InputError names ``group.field``), every float
    must be finite, then the group's own :meth:`_check` runs."""

    _name = ""  # the group's name in dotted paths ("" for the root)

    def __post_init__(self) -> None:
        prefix = f"{self._name}." if self._name else ""
        types = field_types(type(self))
        for f in fields(self):  # type: ignore[arg-type]
            value, tp = getattr(self, f.name), types[f.name]
            if is_dataclass(tp) and isinstance(value, tp):
                continue
            value = convert_value(value, tp, prefix + f.name)
            _check(not isinstance(value, float) or math.isfinite(value),
                   f"{prefix}{f.name}: must be finite, got {value}")
            object.__setattr__(self, f.name, value)
        self._check()

    def _check(self) -> None:
        """The group's range checks (InputError naming ``group.field``)."""


@dataclass(frozen=True)
class ColonParams(_Group):
    """Geometry of the colon tube (metres unless stated)."""

    _name = "colon"

    length: float = 1.25  #: centreline length, m (0.08..5)
    radius: float = 0.025  #: mean lumen radius, m
    radius_variation: float = 0.004  #: slow radius changes: radius +- radius_variation, m
    tortuosity: float = 0.6  #: 0 straight .. 1 strongly bent centreline
    min_bend_radius: float = 0.07  #: smallest radius of curvature of the centreline, m
    fold_spacing: float = 0.035  #: mean axial distance between haustral folds, m
    fold_height: float = 0.38  #: fold height as a fraction of the local radius (0..0.6)
    fold_width: float = 0.0025  #: axial Gaussian sigma of a fold, m
    fold_coverage: float = 0.85  #: probability that each of a fold's three crescents exists
    haustra_bulge: float = 0.08  #: outward bulge between folds, fraction of radius
    taenia_depth: float = 0.06  #: inward dip along the three taeniae, fraction of radius
    relief: float = 0.0004  #: amplitude (std) of the random surface relief of the mesh, m
    polyps: int = 2  #: number of sessile polyps
    polyp_radius: float = 0.004  #: mean polyp base radius, m
    ring_spacing: float = 0.001  #: mesh resolution along the axis, m
    ring_vertices: int = 144  #: mesh vertices around the circumference

    def largest_radius(self) -> float:
        """Largest lumen radius before the haustral bulge, m."""
        return self.radius + self.radius_variation

    def _check(self) -> None:
        c = self
        _check(c.radius > 0, f"colon.radius: must be positive, got {c.radius}")
        _check(c.radius <= 0.2, f"colon.radius: {c.radius} m is not a colon (at most 0.2 m)")
        _check(0 <= c.radius_variation < 0.5 * c.radius,
               f"colon.radius_variation: must be in [0, radius/2), got {c.radius_variation}")
        _check(c.length >= 0.08, f"colon.length: must be at least 0.08 m, got {c.length}")
        _check(c.length <= 5.0, f"colon.length: at most 5 m, got {c.length}")
        _check(0 <= c.tortuosity <= 1, f"colon.tortuosity: must be in [0, 1], got {c.tortuosity}")
        r_max = c.largest_radius()
        _check(c.min_bend_radius > 1.5 * r_max * (1 + c.haustra_bulge),
               f"colon.min_bend_radius: must exceed 1.5 x the largest radius ({1.5 * r_max:.3f} m), "
               f"got {c.min_bend_radius}")
        _check(c.fold_spacing > 0.005, f"colon.fold_spacing: must be above 0.005 m, got {c.fold_spacing}")
        _check(0 <= c.fold_height <= 0.6,
               f"colon.fold_height: must be in [0, 0.6] (fraction of radius), got {c.fold_height}")
        _check(c.fold_width > 0, f"colon.fold_width: must be positive, got {c.fold_width}")
        _check(0 <= c.fold_coverage <= 1, f"colon.fold_coverage: must be in [0, 1], got {c.fold_coverage}")
        _check(0 <= c.haustra_bulge <= 0.3, f"colon.haustra_bulge: must be in [0, 0.3], got {c.haustra_bulge}")
        _check(0 <= c.taenia_depth <= 0.3, f"colon.taenia_depth: must be in [0, 0.3], got {c.taenia_depth}")
        _check(0 <= c.relief <= 0.05 * c.radius, f"colon.relief: must be in [0, radius/20], got {c.relief}")
        _check(0 <= c.polyps <= 100, f"colon.polyps: must be 0..100, got {c.polyps}")
        _check(0 < c.polyp_radius <= 0.5 * c.radius,
               f"colon.polyp_radius: must be in (0, radius/2], got {c.polyp_radius}")
        _check(0.0002 <= c.ring_spacing <= 0.005,
               f"colon.ring_spacing: must be in [0.0002, 0.005] m, got {c.ring_spacing}")
        _check(16 <= c.ring_vertices <= 1024, f"colon.ring_vertices: must be 16..1024, got {c.ring_vertices}")
        n_rings = c.length / c.ring_spacing
        _check(n_rings * c.ring_vertices <= 6_000_000,
               f"colon.ring_spacing: mesh would have {n_rings * c.ring_vertices:.0f} vertices (at most 6e6)")


@dataclass(frozen=True)
class AppearanceParams(_Group):
    """Mucosa, vessels, light and sensor. Angles in degrees."""

    _name = "appearance"

    hue: float = 6.0  #: mucosa hue, degrees (0 red, 30 orange)
    saturation: float = 0.6  #: mucosa HSV saturation, 0..1
    value: float = 0.9  #: mucosa HSV value (albedo brightness), 0..1
    wetness: float = 0.7  #: specular strength and sharpness, 0..1
    vessel_size: float = 0.6  #: 0..1; largest vessel width = 0.15 + 0.6 * vessel_size mm
    vessel_opacity: float = 0.3  #: 0..1
    vessel_density: float = 1.0  #: relative number of vessel trees per area, 0..5
    light_angle: float = 150.0  #: full cone angle of the light, degrees (0..180]
    light_intensity: float = 0.74  #: relative power of the light
    light_offset: float = 0.0  #: distance of the light from the lens, m (0 = co-located; at most colon.radius/2)
    shadows: bool = True  #: cast shadow rays (only matters when light_offset > 0)
    auto_exposure: float = 0.85  #: 0 fixed exposure .. 1 full automatic light control
    micro_relief: float = 0.25  #: strength of the fine bump map that breaks highlights up, 0..1
    vignette: float = 0.7  #: 0..1
    bloom: float = 0.3  #: 0..1
    grain: float = 0.0  #: sensor noise level, 0..20; noise std = 0.01 * grain (of full range)
    motion_blur: float = 0.0  #: 0..1: fraction of the frame interval the shutter is open
    texel: float = 0.00025  #: texture atlas resolution, m per texel

    def _check(self) -> None:
        a = self
        for name in ("saturation", "value", "wetness", "vessel_size", "vessel_opacity", "auto_exposure",
                     "micro_relief", "vignette", "bloom", "motion_blur"):
            v = getattr(a, name)
            _check(0 <= v <= 1, f"appearance.{name}: must be in [0, 1], got {v}")
        _check(0 <= a.vessel_density <= 5, f"appearance.vessel_density: must be in [0, 5], got {a.vessel_density}")
        _check(0 < a.light_angle <= 180,
               f"appearance.light_angle: full cone angle must be in (0, 180] degrees, got {a.light_angle}")
        _check(a.light_intensity > 0, f"appearance.light_intensity: must be positive, got {a.light_intensity}")
        _check(a.light_offset >= 0, f"appearance.light_offset: must be at least 0 m, got {a.light_offset}")
        _check(0 <= a.grain <= 20, f"appearance.grain: must be in [0, 20], got {a.grain}")
        _check(0.00005 <= a.texel <= 0.002, f"appearance.texel: must be in [0.00005, 0.002] m, got {a.texel}")


@dataclass(frozen=True)
class CameraParams(_Group):
    """Pinhole camera; ``fov`` is the horizontal field of view in degrees."""

    _name = "camera"

    width: int = 512  #: frame width, pixels (16..4096)
    height: int = 512  #: frame height, pixels (16..4096)
    fov: float = 110.0  #: horizontal field of view, degrees (0..180)
    depth_scale: float = 10000.0  #: depth PNG units per metre (the colon's longest depth must fit in uint16)

    def _check(self) -> None:
        cam = self
        for name in ("width", "height"):
            v = getattr(cam, name)
            _check(16 <= v <= 4096, f"camera.{name}: frames must be 16..4096 pixels, got {v}")
        _check(0 < cam.fov < 180, f"camera.fov: horizontal field of view must be in (0, 180) degrees, got {cam.fov}")
        _check(cam.depth_scale > 0, f"camera.depth_scale: must be positive, got {cam.depth_scale}")


@dataclass(frozen=True)
class PathParams(_Group):
    """Camera trajectory. Event rates are expected events per 1000 frames."""

    _name = "path"

    kind: str = "A"  #: A (insertion), B (withdrawal) or random (the paper's RP; also accepted: RP)
    frames: int = 300  #: number of frames
    fps: float = 30.0  #: frames per second, only for the timestamps in poses.txt
    max_step: float = 0.005  #: largest base step per frame, m (bursts go faster)
    coverage: float = 1.0  #: fraction of the usable colon length to traverse, (0, 1]
    loop: bool = False  #: forward then backward over the same stretch (loop closures)
    roll: float = 25.0  #: amplitude of the slow roll, degrees
    lateral: float = 0.35  #: wandering off-axis offset, fraction of the free radius
    closeups: float = 3.0  #: looks at the wall at close range, per 1000 frames
    bursts: float = 2.0  #: fast-motion bursts, per 1000 frames
    occlusions: float = 2.0  #: approaches that fill the view with a fold, per 1000 frames
    roll_events: float = 3.0  #: quick roll turns, per 1000 frames
    burst_factor: float = 4.0  #: speed multiplier during a burst
    #: fastest turn of the view during an event's ramps (close-ups, fold approaches, burst jolts,
    #: roll turns), degrees per second at ``fps``; ramps lengthen to respect it. None: ramps
    #: fixed in frames (the simulator before 2026-12; close-ups then turn up to ~38 deg/frame)
    max_turn_rate: float | None = 120.0
    #: fastest camera motion during the ramps of close-ups and fold approaches, m/s at ``fps``
    #: (bursts are fast on purpose and keep ``burst_factor``); None: no bound
    max_event_speed: float | None = 0.06
    min_wall_distance: float = 0.004  #: the camera keeps at least this distance to the mesh, m

    def __post_init__(self) -> None:
        if isinstance(self.kind, str):
            object.__setattr__(self, "kind", normalise_path_kind(self.kind))
        super().__post_init__()

    def _check(self) -> None:
        path = self
        _check(path.frames >= 1, f"path.frames: must be at least 1, got {path.frames}")
        _check(path.frames <= 1_000_000, f"path.frames: at most 1e6, got {path.frames}")
        _check(path.fps > 0, f"path.fps: must be positive, got {path.fps}")
        _check(0 < path.max_step <= 0.02, f"path.max_step: must be in (0, 0.02] m per frame, got {path.max_step}")
        _check(0 < path.coverage <= 1, f"path.coverage: must be in (0, 1], got {path.coverage}")
        _check(0 <= path.lateral <= 1, f"path.lateral: must be in [0, 1], got {path.lateral}")
        _check(0 <= path.roll <= 180, f"path.roll: must be in [0, 180] degrees, got {path.roll}")
        for name in ("closeups", "bursts", "occlusions", "roll_events"):
            v = getattr(path, name)
            _check(0 <= v <= 100, f"path.{name}: events per 1000 frames must be in [0, 100], got {v}")
        _check(1 <= path.burst_factor <= 10, f"path.burst_factor: must be in [1, 10], got {path.burst_factor}")
        _check(path.max_turn_rate is None or 1 <= path.max_turn_rate <= 10000,
               f"path.max_turn_rate: must be in [1, 10000] degrees per second (or None), got {path.max_turn_rate}")
        _check(path.max_event_speed is None or 0.001 <= path.max_event_speed <= 10,
               f"path.max_event_speed: must be in [0.001, 10] m/s (or None), got {path.max_event_speed}")
        _check(path.min_wall_distance > 0, f"path.min_wall_distance: must be positive, got {path.min_wall_distance}")


@dataclass(frozen=True)
class NuisanceParams(_Group):
    """What real recordings add to the rendered frames (:mod:`datamodules.synthetic.nuisances`);
    all off by default. Shares are the expected fraction of frames, 0..1; sizes in pixels of
    the output frame unless stated."""

    _name = "nuisance"

    border: str = "none"  #: the scope's black border: none, circle, octagon, cut_corners, letterbox
    border_scale: float = 1.0  #: circle diameter / octagon width over the frame's smaller side, 0.5..1.5
    border_corner: float = 0.15  #: cut_corners: leg of each cut corner, fraction of the smaller side
    border_bars: float = 0.2  #: letterbox: the two bars' share of the frame height
    border_level: float = 6.0  #: mean grey level of the border, 0..12 of 255 (with a little noise)
    overlay: bool = False  #: burned-in label, clock (HH:MM:SS of video time) and icon
    overlay_text: str = "C3F SIM"  #: the label (at most 40 printable ASCII characters)
    motion_blur_share: float = 0.0  #: frames blurred along a random direction
    motion_blur_px: float = 9.0  #: length of the motion blur's line kernel, px
    defocus_share: float = 0.0  #: frames blurred by a disc (out of focus)
    defocus_px: float = 3.0  #: radius of the defocus disc, px
    washed_out_share: float = 0.0  #: over-exposed frames
    washed_out_strength: float = 0.8  #: 0..1: how far brightness and contrast are pushed
    repeat_share: float = 0.0  #: frames that repeat the previous one (re-encoded as JPEG)
    repeat_quality: int = 85  #: JPEG quality of a repeated frame, 1..100

    def __post_init__(self) -> None:
        if isinstance(self.border, str):
            object.__setattr__(self, "border", self.border.strip().lower().replace("-", "_"))
        super().__post_init__()

    def active(self) -> bool:
        """True when some nuisance is on: a border, the overlay or a share above 0 (otherwise the
        frames are written exactly as rendered)."""
        shares = (self.motion_blur_share, self.defocus_share, self.washed_out_share, self.repeat_share)
        return self.border != "none" or self.overlay or any(v > 0 for v in shares)

    def _check(self) -> None:
        n = self
        _check(n.border in BORDERS, f"nuisance.border: unknown border {n.border!r} (choose {', '.join(BORDERS)})")
        _check(0.5 <= n.border_scale <= 1.5, f"nuisance.border_scale: must be in [0.5, 1.5], got {n.border_scale}")
        _check(0 <= n.border_corner <= 0.5, f"nuisance.border_corner: must be in [0, 0.5], got {n.border_corner}")
        _check(0 <= n.border_bars <= 0.8, f"nuisance.border_bars: must be in [0, 0.8], got {n.border_bars}")
        _check(0 <= n.border_level <= 12,
               f"nuisance.border_level: must be in [0, 12] grey levels, got {n.border_level}")
        text = n.overlay_text
        _check(len(text) <= 40 and all(" " <= ch <= "~" for ch in text),
               f"nuisance.overlay_text: at most 40 printable ASCII characters, got {text!r}")
        for name in ("motion_blur_share", "defocus_share", "washed_out_share", "repeat_share"):
            v = getattr(n, name)
            _check(0 <= v <= 1, f"nuisance.{name}: must be in [0, 1], got {v}")
        _check(1 <= n.motion_blur_px <= 200,
               f"nuisance.motion_blur_px: must be in [1, 200] px, got {n.motion_blur_px}")
        _check(0.5 <= n.defocus_px <= 100, f"nuisance.defocus_px: must be in [0.5, 100] px, got {n.defocus_px}")
        _check(0 < n.washed_out_strength <= 1,
               f"nuisance.washed_out_strength: must be in (0, 1], got {n.washed_out_strength}")
        _check(1 <= n.repeat_quality <= 100,
               f"nuisance.repeat_quality: must be a JPEG quality 1..100, got {n.repeat_quality}")


@dataclass(frozen=True)
class SimParams(_Group):
    """All parameters of one simulated sequence."""

    seed: int = 0  #: random seed; with the other parameters it fixes the sequence byte for byte
    preset: str = "default"  #: the preset these parameters started from: default, seq1..seq8 (the paper's) or tiny
    colon: ColonParams = field(default_factory=ColonParams)
    appearance: AppearanceParams = field(default_factory=AppearanceParams)
    camera: CameraParams = field(default_factory=CameraParams)
    path: PathParams = field(default_factory=PathParams)
    nuisance: NuisanceParams = field(default_factory=NuisanceParams)
    #: effects of a real recording on the frames (fluid, bubbles, highlights, light, sensor noise,
    #: interlacing, JPEG, video; :mod:`datamodules.synthetic.recording`), all off by default
    recording: RecordingParams = field(default_factory=RecordingParams)

    def to_dict(self) -> dict[str, Any]:
        """Every parameter as nested plain dicts (params.json's ``params``)."""
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> SimParams:
        """Inverse of :meth:`to_dict` (partial mappings start from their ``preset``); unknown keys
        are an InputError naming them."""
        return tree_from_mapping(SIM_SETTINGS.tree(str(data.get("preset") or SIM_SETTINGS.default)), data)

    def _check(self) -> None:
        """The checks that join two groups: light, texture, camera and path against the colon's size."""
        c, a, cam, path = self.colon, self.appearance, self.camera, self.path
        _check(0 <= self.seed < 2**63, f"seed: must be a non-negative integer below 2**63, got {self.seed}")
        _check(self.preset in PRESETS, f"preset: unknown preset {self.preset!r} (choose from {', '.join(PRESETS)})")
        _check(a.light_offset <= 0.5 * c.radius,
               f"appearance.light_offset: must be in [0, colon.radius/2], got {a.light_offset}")
        circumference = 2 * math.pi * c.largest_radius()
        _check(circumference / a.texel < 16000 and 1.8 * c.length / a.texel < 32000,
               f"appearance.texel: {a.texel} m makes the texture atlas too large for this colon")
        longest = c.length + 2 * c.largest_radius() * (1 + c.haustra_bulge)  # no line inside the tube is longer
        _check(longest * cam.depth_scale <= 65535,
               f"camera.depth_scale: {cam.depth_scale} units/m cannot store depths up to {longest:.2f} m in uint16")
        # the camera on the axis must clear the highest fold by min_wall_distance
        axis_clearance = (c.radius - c.radius_variation) * (1 - c.taenia_depth) * (1 - c.fold_height) - 3 * c.relief
        _check(path.min_wall_distance < 0.7 * axis_clearance,
               f"path.min_wall_distance: must be in (0, {0.7 * axis_clearance:.4f}) m for this colon"
               f" (radius and fold height leave {axis_clearance * 1000:.1f} mm on the axis),"
               f" got {path.min_wall_distance}")


def parse_size(value: Any) -> tuple[int, int]:
    """Frame size in pixels: ``256``, ``"256"``, ``"320x240"`` or ``(320, 240)`` -> (width, height);
    InputError naming ``size``."""
    try:
        if isinstance(value, (tuple, list)) and len(value) == 2:
            w, h = int(value[0]), int(value[1])
        elif isinstance(value, str) and "x" in value.lower():
            a, b = value.lower().split("x")
            w, h = int(a), int(b)
        else:
            w = h = int(value)
    except (TypeError, ValueError):
        raise InputError(f"size: cannot use {value!r} (expected N or WxH)") from None
    if w < 16 or h < 16:
        raise InputError(f"size: frames must be at least 16x16 pixels, got {w}x{h}")
    return w, h


def check_output(out: str | Path, overwrite: bool) -> Path:
    """Refuse an output folder that would destroy data (InputError); nothing is written."""
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise InputError(f"out: {out} exists and is not a folder")
    if out.is_dir() and any(out.iterdir()) and not overwrite:
        raise InputError(f"out: {out} exists and is not empty (use --overwrite to replace it)")
    return out


def check_layout(layout: str) -> str:
    """The layout's name (aliases resolved); InputError for an unknown one."""
    layout = LAYOUT_ALIASES.get(layout, layout)
    if layout not in LAYOUTS:
        raise InputError(f"layout: unknown layout {layout!r} (choose from {', '.join(LAYOUTS)})")
    return layout


def normalise_path_kind(kind: str) -> str:
    """``A``, ``B``, ``random`` or ``RP`` (any case) -> ``A``, ``B`` or ``random``; InputError naming ``path.kind``."""
    k = PATH_ALIASES.get(str(kind).strip().lower())
    if k is None:
        raise InputError(f"path.kind: unknown path {kind!r} (choose A, B or random/RP)")
    return k


# ---------------------------------------------------------------------- paper presets

#: Column names of the paper's appendix table, in its order.
_PAPER_COLUMNS = ("path", "hue", "saturation", "value", "wetness", "vessel_size", "vessel_opacity", "angle",
                  "intensity", "fov", "grain")
#: The appendix table of the paper (Unity simulator values, verbatim; rows in the order of
#: ``_PAPER_COLUMNS``). Shared by all eight: trip 150 s at 30 shots/s, 512x512, distance 0,
#: shadow on, dynamic off, vignette on, bloom on.
PAPER_TABLE: dict[str, dict[str, Any]] = {name: dict(zip(_PAPER_COLUMNS, row)) for name, row in {
    "seq1": ("A", 0, 72, 100, 88, 60, 30, 150, 74, 110, 0),
    "seq2": ("RP", 0, 72, 100, 88, 60, 30, 150, 74, 110, 0),
    "seq3": ("B", 3, 90, 100, 56, 60, 30, 150, 59, 110, 1),
    "seq4": ("RP", 3, 90, 100, 56, 60, 30, 150, 59, 110, 1),
    "seq5": ("RP", 100, 78, 52, 40, 60, 30, 150, 62, 110, 3),
    "seq6": ("RP", 100, 78, 52, 40, 60, 30, 150, 62, 110, 3),
    "seq7": ("RP", 100, 78, 52, 40, 60, 30, 150, 62, 110, 3),
    "seq8": ("RP", 100, 78, 52, 40, 60, 30, 150, 62, 110, 3),
}.items()}
PAPER_COMMON = dict(trip_duration_s=150, shots_per_s=30, resolution=512, distance=0, shadow=True,
                    dynamic=False, vignette=True, bloom=True)

#: What makes a sequence tiny (preset ``tiny``, :mod:`datamodules.synthetic.fixture`): a 15 cm colon,
#: a coarse mesh and texture, no events; 8 frames of 64 x 64 pixels.
TINY: dict[str, dict[str, Any]] = {
    "colon": {"length": 0.15, "ring_spacing": 0.001, "ring_vertices": 96, "polyps": 1},
    "appearance": {"texel": 0.0004},
    "camera": {"width": 64, "height": 64},
    "path": {"kind": "A", "frames": 8, "max_step": 0.004, "closeups": 0.0, "bursts": 0.0, "occlusions": 0.0,
             "roll_events": 0.0},
}

PRESETS = ("default", *PAPER_TABLE, "tiny")


def paper_preset(name: str) -> SimParams:
    """Physical parameters for one of the paper's sequences (``seq1`` .. ``seq8``).

    Mapping of the Unity slider values (this project's choice; the sliders' units are not
    published):

    - hue h (0..100)            -> mucosa hue 5 + 0.12 h degrees (0: pink-red, 100: orange)
    - saturation s (0..100)     -> 0.35 + 0.45 s/100
    - value v (0..100)          -> 0.4 + 0.55 v/100
    - wetness w, vessel size, vessel opacity (0..100) -> w/100, size/100, opacity/100
    - light angle               -> full cone angle in degrees; intensity i -> i/100
    - distance 0                -> light co-located with the lens (no visible shadows)
    - vignette / bloom on       -> 0.7 / 0.3; grain g -> g (noise std 0.01 g)
    - path A / B / RP           -> insertion / withdrawal / random
    - 150 s at 30 shots/s       -> 4500 frames at 30 fps, 512x512
    """
    key = _preset_key(name)
    if key == "default":
        return SimParams()
    if key not in PAPER_TABLE:
        raise InputError(f"preset: unknown preset {name!r} (choose from {', '.join(PRESETS)})")
    t = PAPER_TABLE[key]
    appearance = AppearanceParams(
        hue=5.0 + 0.12 * t["hue"], saturation=0.35 + 0.45 * t["saturation"] / 100.0,
        value=0.4 + 0.55 * t["value"] / 100.0, wetness=t["wetness"] / 100.0,
        vessel_size=t["vessel_size"] / 100.0, vessel_opacity=t["vessel_opacity"] / 100.0,
        light_angle=float(t["angle"]), light_intensity=t["intensity"] / 100.0, light_offset=0.0,
        shadows=PAPER_COMMON["shadow"], vignette=0.7 if PAPER_COMMON["vignette"] else 0.0,
        bloom=0.3 if PAPER_COMMON["bloom"] else 0.0, grain=float(t["grain"]))
    size = PAPER_COMMON["resolution"]
    kind = normalise_path_kind(t["path"])
    events: dict[str, float] = {}
    if kind == "B":  # withdrawal: the inspection phase, more looks at the wall
        events = {"closeups": 5.0}
    elif kind == "random":
        events = {"closeups": 4.0, "bursts": 6.0, "occlusions": 4.0, "roll_events": 6.0, "roll": 45.0}
    path = PathParams(kind=kind, frames=PAPER_COMMON["trip_duration_s"] * PAPER_COMMON["shots_per_s"],
                      fps=float(PAPER_COMMON["shots_per_s"]), **events)
    return SimParams(seed=int(key[3:]), preset=key, appearance=appearance,
                     camera=CameraParams(width=size, height=size, fov=float(t["fov"])), path=path)


def tiny_preset() -> SimParams:
    """The ``tiny`` preset: the default parameters with :data:`TINY` (seed 0)."""
    return tree_from_mapping(SimParams(preset="tiny"), TINY)


def _preset_key(name: str) -> str:
    key = str(name).strip().lower().replace(" ", "").replace(".", "")
    return key or "default"


def get_preset(name: str) -> SimParams:
    """``default``, ``seq1`` .. ``seq8`` or ``tiny`` (case-insensitive; ``Seq. 3`` also works)."""
    key = _preset_key(name)
    if key not in SIM_SETTINGS.presets:
        raise InputError(f"preset: unknown preset {name!r} (choose from {', '.join(PRESETS)})")
    return SIM_SETTINGS.tree(key)


#: The simulator's settings (``generate --preset/--config/--set/--print-config``): its presets,
#: the params.json key that replays a sequence, the command that reads a settings file.
SIM_SETTINGS: SettingsSpec[SimParams] = SettingsSpec(
    presets={"default": SimParams, **{name: partial(paper_preset, name) for name in PAPER_TABLE},
             "tiny": tiny_preset},
    default="default", record_key="params",
    usage="python -m datamodules.synthetic generate --out OUT --config THIS_FILE")
