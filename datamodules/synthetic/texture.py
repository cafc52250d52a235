"""Mucosa texture defined on the colon surface: colour, vessel network and micro-relief.

The texture lives in an atlas indexed by the surface coordinates of :mod:`colon`: column =
``u / texel`` (u: surface arc length along the tube, metres), row = ``theta * rows / 2 pi``
(wrapping around). Because it is attached to the surface, every frame sees the same texture
at the same place (multi-view consistency for SLAM and feature training).

Atlas contents, all float32:

- ``albedo``: linear RGB reflectance in [0, 1] (HSV-controlled mucosa, slow colour and
  brightness variation, fine mottling, two layers of branching vessels, polyp tint);
- ``slope``: surface slope (du, dtheta directions, dimensionless) of a fine bump map
  that breaks the wet highlights into glints (its RMS is set by ``micro_relief``).

Both have a mip pyramid; :meth:`TextureAtlas.sample` does trilinear look-ups with OpenCV
``remap`` (wrapping in theta) given each pixel's footprint on the surface.
"""

from __future__ import annotations

import colorsys
import math
from dataclasses import dataclass

import cv2
import numpy as np

from datamodules.synthetic.colon import Colon
from datamodules.synthetic.noise import noise_2d, wrap_rows_blur
from datamodules.synthetic.params import AppearanceParams

MIP_LEVELS = 6


def srgb_to_linear(c: np.ndarray | float) -> np.ndarray:
    return np.power(np.clip(c, 0.0, 1.0), 2.2)


def hsv_colour(hue_deg: float, sat: float, val: float) -> np.ndarray:
    """Linear RGB of an sRGB colour given in HSV (hue in degrees)."""
    rgb = colorsys.hsv_to_rgb((hue_deg % 360.0) / 360.0, float(np.clip(sat, 0, 1)), float(np.clip(val, 0, 1)))
    return srgb_to_linear(np.array(rgb, dtype=np.float32))


@dataclass
class TextureAtlas:
    """Mip pyramids of the atlas: ``rgbs`` = (albedo R, G, B, slope along u), ``slope_v``."""

    texel: float  # metres per column (u)
    rows: int  # texels around the circumference
    rgbs: list[np.ndarray]  # mip levels, (rows/2^l, cols/2^l, 4) float32
    slope_v: list[np.ndarray]  # mip levels, (rows/2^l, cols/2^l) float32

    @property
    def albedo(self) -> np.ndarray:
        """Finest albedo level, (rows, cols, 3) linear RGB."""
        return self.rgbs[0][..., :3]

    def sample(self, u: np.ndarray, theta: np.ndarray, footprint: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Trilinear look-up at (N,) surface coordinates; ``footprint`` = pixel size on the surface, m.

        Returns (N, 4) = albedo RGB + slope along u, and (N,) slope along theta. Pixels are
        sorted by mip level so that each level is fetched only for the pixels that need it.
        """
        n = len(u)
        x0 = (u * (1.0 / self.texel)).astype(np.float32)
        y0 = (theta * (self.rows / (2 * math.pi))).astype(np.float32)
        lod = np.clip(np.log2(np.maximum(footprint, 1e-9) * (1.0 / self.texel)), 0.0,
                      MIP_LEVELS - 1.0).astype(np.float32)
        lo = lod.astype(np.int8)  # floor, lod >= 0
        order = np.argsort(lo, kind="stable")
        lo_s = lo[order]
        frac_s = (lod - lo)[order]
        xs, ys = x0[order], y0[order]
        ends = np.cumsum(np.bincount(lo_s, minlength=MIP_LEVELS))
        starts = np.concatenate([[0], ends[:-1]])
        out4 = np.zeros((n, 4), np.float32)
        out1 = np.zeros(n, np.float32)
        for level in range(MIP_LEVELS):
            a = starts[level - 1] if level > 0 else starts[0]
            b = ends[level]
            if b <= a:
                continue
            m = b - a
            width = 256
            pad = (-m) % width
            sc = np.float32(0.5**level)
            mx = np.concatenate([xs[a:b] * sc, np.zeros(pad, np.float32)]).reshape(-1, width)
            my = np.concatenate([ys[a:b] * sc, np.zeros(pad, np.float32)]).reshape(-1, width)
            r4 = cv2.remap(self.rgbs[level], mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP).reshape(-1, 4)[:m]
            r1 = cv2.remap(self.slope_v[level], mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP).reshape(-1)[:m]
            f = frac_s[a:b]
            wgt = np.where(lo_s[a:b] == level, 1.0 - f, f).astype(np.float32)
            out4[a:b] += wgt[:, None] * r4
            out1[a:b] += wgt * r1
        res4 = np.empty_like(out4)
        res1 = np.empty_like(out1)
        res4[order] = out4
        res1[order] = out1
        return res4, res1


def _pyr_down_wrap(img: np.ndarray) -> np.ndarray:
    """Halve an atlas level: Gaussian pyramid step, wrapping in rows, reflecting in columns."""
    p = 2
    padded = cv2.copyMakeBorder(img, p, p, 0, 0, cv2.BORDER_WRAP)
    padded = cv2.copyMakeBorder(padded, 0, 0, p, p, cv2.BORDER_REFLECT_101)
    down = cv2.pyrDown(padded)
    r, c = img.shape[0] // 2, img.shape[1] // 2
    return np.ascontiguousarray(down[1 : 1 + r, 1 : 1 + c])


def build_atlas(colon: Colon, a: AppearanceParams, rng: np.random.Generator) -> TextureAtlas:
    """Draw the texture atlas of ``colon`` from ``rng`` (deterministic)."""
    texel = a.texel
    radius = colon.params.radius
    step = 2**MIP_LEVELS
    rows = step * max(1, round(2 * math.pi * radius / texel / step))
    cols = step * math.ceil((float(colon.tex_u.max()) / texel + 4) / step)

    albedo = _mucosa(a, rng, rows, cols)
    # vessels: deep (wide, blurred, dark purple-red) and superficial capillaries (thin, red)
    deep, fine = _vessel_masks(rng, rows, cols, texel, a.vessel_size, a.vessel_density)
    deep = wrap_rows_blur(deep, 1.1)
    fine = wrap_rows_blur(fine, 0.5)
    tint_deep = np.array([0.55, 0.20, 0.30], np.float32)
    tint_fine = np.array([0.80, 0.32, 0.33], np.float32)
    k_deep = min(1.0, 2.6 * a.vessel_opacity)
    k_fine = min(1.0, 2.2 * a.vessel_opacity)
    albedo = albedo * (1.0 - k_deep * deep[..., None] * (1.0 - tint_deep))
    albedo = albedo * (1.0 - k_fine * fine[..., None] * (1.0 - tint_fine))
    _tint_polyps(albedo, colon, texel)
    albedo = np.clip(albedo, 0.0, 1.0).astype(np.float32)
    slope = _micro_relief(rng, rows, cols, deep, a.micro_relief)

    rgbs = [np.ascontiguousarray(np.concatenate([albedo, slope[..., :1]], axis=-1))]
    slope_v = [np.ascontiguousarray(slope[..., 1])]
    for _ in range(1, MIP_LEVELS):
        rgbs.append(_pyr_down_wrap(rgbs[-1]))
        slope_v.append(_pyr_down_wrap(slope_v[-1]))
    return TextureAtlas(texel=texel, rows=rows, rgbs=rgbs, slope_v=slope_v)


def _mucosa(a: AppearanceParams, rng: np.random.Generator, rows: int, cols: int) -> np.ndarray:
    """(rows, cols, 3) linear RGB of the bare mucosa: the base HSV colour, blended towards a
    yellower and a redder variant, with slow and fine brightness variation."""
    c0 = hsv_colour(a.hue, a.saturation, a.value)
    c_yellow = hsv_colour(a.hue + 9.0, a.saturation * 0.85, min(1.0, a.value * 1.02))
    c_red = hsv_colour(a.hue - 5.0, min(1.0, a.saturation * 1.18), a.value * 0.88)
    t = noise_2d(rng, rows, cols, 64)[..., None]
    albedo = c0 + 0.3 * np.maximum(t, 0) * (c_yellow - c0) + 0.3 * np.maximum(-t, 0) * (c_red - c0)
    shade = (1.0 + 0.07 * noise_2d(rng, rows, cols, 32) + 0.03 * noise_2d(rng, rows, cols, 8)
             + 0.025 * noise_2d(rng, rows, cols, 2))
    return albedo * np.clip(shade, 0.6, 1.4)[..., None]


def _tint_polyps(albedo: np.ndarray, colon: Colon, texel: float) -> None:
    """Tint the (rows, cols, 3) atlas ``albedo`` (``texel`` m per column) redder and slightly
    brighter around each polyp of ``colon``, in place."""
    rows, cols = albedo.shape[:2]
    for pol in colon.polyps:
        j = int(round(pol.s / colon.ring_spacing))
        k = int(round(pol.theta / (2 * math.pi) * len(colon.theta))) % len(colon.theta)
        cu = colon.grid_u[j, k] / texel
        cv = pol.theta * rows / (2 * math.pi)
        rad = 1.6 * pol.radius / texel
        c_lo, c_hi = max(0, int(cu - 2 * rad)), min(cols, int(cu + 2 * rad) + 1)
        if c_hi <= c_lo:
            continue
        yy = np.arange(rows, dtype=np.float32)[:, None]
        dy = (yy - cv + rows / 2) % rows - rows / 2
        dx = np.arange(c_lo, c_hi, dtype=np.float32)[None] - cu
        blob = np.exp(-0.5 * (dx**2 + dy**2) / (0.6 * rad) ** 2)[..., None]
        albedo[:, c_lo:c_hi] *= 1.0 + blob * np.array([0.08, -0.18, -0.12], np.float32)


def _micro_relief(rng: np.random.Generator, rows: int, cols: int, deep: np.ndarray,
                  micro_relief: float) -> np.ndarray:
    """(rows, cols, 2) float32 slopes (along u, along theta; dimensionless) of the fine bump map:
    round bumps (0.5-2 mm, they give compact glints), a finer grain and the bulge of the
    ``deep`` vessels; RMS slope = 0.8 * ``micro_relief``."""
    h = 1.0 * _bumps(rng, rows, cols, 7.0, 0.03) + 0.6 * _bumps(rng, rows, cols, 3.5, 0.08)
    h += 0.04 * noise_2d(rng, rows, cols, 2) + 0.3 * deep  # deep vessels bulge a little
    du = (np.roll(h, -1, axis=1) - np.roll(h, 1, axis=1)) * 0.5
    dv = (np.roll(h, -1, axis=0) - np.roll(h, 1, axis=0)) * 0.5
    rms = math.sqrt(float(np.mean(du**2 + dv**2))) + 1e-9
    return (np.stack([du, dv], axis=-1) * (0.8 * micro_relief / rms)).astype(np.float32)


def _bumps(rng: np.random.Generator, rows: int, cols: int, sigma: float, density: float) -> np.ndarray:
    """Sum of Gaussian bumps (sigma texels, ``density`` per texel^2, random heights), wrapping in rows."""
    count = int(rows * cols * density / sigma**2)
    img = np.zeros((rows, cols), np.float32)
    r = rng.integers(0, rows, count)
    c = rng.integers(0, cols, count)
    np.add.at(img, (r, c), rng.uniform(0.5, 1.0, count).astype(np.float32))
    return wrap_rows_blur(img, sigma) * np.float32(sigma**2)


# ---------------------------------------------------------------------- vessels


def _walk(rng: np.random.Generator, start: np.ndarray, angle: np.ndarray, n_steps: int,
          step: float) -> tuple[np.ndarray, np.ndarray]:
    """Random walks of B branches: points (B, n+1, 2) and headings (B, n+1), in texels."""
    b = len(start)
    turn = rng.normal(0.0, 0.07, (b, n_steps)) + rng.normal(0.0, 0.015, (b, 1))
    heading = np.concatenate([angle[:, None], angle[:, None] + np.cumsum(turn, axis=1)], axis=1)
    d = step * np.stack([np.cos(heading[:, :-1]), np.sin(heading[:, :-1])], axis=-1)
    pts = np.concatenate([start[:, None, :], start[:, None, :] + np.cumsum(d, axis=1)], axis=1)
    return pts, heading


def _vessel_masks(rng: np.random.Generator, rows: int, cols: int, texel: float, size: float,
                  density: float) -> tuple[np.ndarray, np.ndarray]:
    """Two (rows, cols) float32 masks in [0, 1] of branching vessel trees (wrapping in rows)."""
    area_cm2 = rows * cols * texel * texel * 1e4
    w_max = (0.15 + 0.6 * size) * 1e-3
    step_m = 0.0004
    step = step_m / texel
    canvases = {"deep": np.zeros((3 * rows, cols), np.uint8), "fine": np.zeros((3 * rows, cols), np.uint8)}
    layers = {
        "deep": (int(round(area_cm2 * 0.05 * density)), w_max, (0.02, 0.06), 3),
        "fine": (int(round(area_cm2 * 0.35 * density)), 0.4 * w_max, (0.004, 0.012), 2),
    }
    for name, (count, width, length, generations) in layers.items():
        if count == 0:
            continue
        start = np.stack([rng.uniform(0, cols, count), rng.uniform(rows, 2 * rows, count)], axis=1)
        angle = rng.uniform(0, 2 * np.pi, count)
        widths = width * rng.uniform(0.6, 1.0, count)
        lengths = rng.uniform(*length, count)
        strokes: list[tuple[np.ndarray, float]] = []
        for _gen in range(generations + 1):
            if len(start) == 0:
                break
            n_steps = max(1, int(math.ceil(lengths.max() / step_m)))
            pts, heading = _walk(rng, start, angle, n_steps, step)
            n_i = np.maximum(1, np.ceil(lengths / step_m).astype(int))
            for b in range(len(start)):
                strokes.append((pts[b, : n_i[b] + 1], widths[b]))
            # children branch off at random points along their parent
            n_child = rng.poisson(lengths / 0.007)
            parent = np.repeat(np.arange(len(start)), n_child)
            if len(parent) == 0:
                break
            at = (rng.random(len(parent)) * n_i[parent]).astype(int)
            side = np.where(rng.random(len(parent)) < 0.5, -1.0, 1.0)
            start = pts[parent, at]
            angle = heading[parent, at] + side * rng.uniform(0.35, 0.9, len(parent))
            widths = widths[parent] * rng.uniform(0.55, 0.8, len(parent))
            lengths = lengths[parent] * rng.uniform(0.4, 0.75, len(parent))
            keep = widths > 0.04e-3
            start, angle, widths, lengths = start[keep], angle[keep], widths[keep], lengths[keep]
        _draw(canvases[name], strokes, texel)
    out = []
    for name in ("deep", "fine"):
        c = canvases[name]
        folded = np.maximum(np.maximum(c[:rows], c[rows : 2 * rows]), c[2 * rows :])
        out.append(folded.astype(np.float32) / 255.0)
    return out[0], out[1]


def _draw(canvas: np.ndarray, strokes: list[tuple[np.ndarray, float]], texel: float) -> None:
    """Anti-aliased polylines grouped by (thickness, intensity); faint first, strong on top."""
    groups: dict[tuple[int, int], list[np.ndarray]] = {}
    for pts, width in strokes:
        t = width / texel
        if t >= 1.5:
            key = (int(round(t)), 255)
        else:
            key = (1, int(round(255 * min(1.0, t / 1.3) / 16)) * 16 or 16)
        groups.setdefault(key, []).append(np.round(pts * 16).astype(np.int32))
    for (thick, colour) in sorted(groups, key=lambda k: (k[1], k[0])):
        cv2.polylines(canvas, groups[(thick, colour)], False, int(min(colour, 255)), thickness=thick,
                      lineType=cv2.LINE_AA, shift=4)
