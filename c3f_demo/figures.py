"""Figures of the demo report (PNG files in ``DIR/figures``): sample frames beside predicted and
true depth, the mesh renders, and for a user's video the tissue mask over a frame and a strip of
what became of each frame. Depths in metres (the colour bar is labelled in cm)."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import open3d as o3d

from c3f_demo.render import crop_near, render_views
from c3f_slam.io import Sequence
from c3f_slam.io.atomic import atomic_write
from c3f_slam.models import DepthModel


def write_png(path: Path, rgb: np.ndarray) -> None:
    with atomic_write(path) as tmp:
        cv2.imwrite(str(tmp), cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2BGR))


def colour_depth(depth: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """(H, W, 3) uint8 RGB: depth mapped to TURBO between ``lo`` and ``hi`` metres, 0 = black."""
    x = np.clip((depth - lo) / max(hi - lo, 1e-9), 0, 1)
    rgb = cv2.cvtColor(cv2.applyColorMap((x * 255).astype(np.uint8), cv2.COLORMAP_TURBO), cv2.COLOR_BGR2RGB)
    rgb[~(depth > 0)] = 0
    return rgb


def _label(img: np.ndarray, text: str) -> np.ndarray:
    out = img.copy()
    cv2.putText(out, text, (4, 14), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (255, 255, 255), 1, cv2.LINE_AA)
    return out


def depth_samples(seq_dir: Path, models: dict[str, Path], n: int, out: Path) -> dict:
    """Rows of [frame | predicted depth of each model | true depth] for ``n`` evenly spaced
    frames, one colour range (the true depth's 2nd-98th percentile over those frames).
    ``models``: column label -> depth ONNX file. Each prediction is multiplied by the metric scale
    its export recorded (what ``c3f_slam run`` uses), when there is one. Returns the frames, the
    range, the labels and their scales."""
    seq = Sequence(seq_dir)
    idx = np.linspace(0, len(seq) - 1, n).round().astype(int).tolist()
    rgbs = [seq.read_rgb(i) for i in idx]
    gts = [seq.read_depth(i) for i in idx]
    valid = np.concatenate([g[g > 0] for g in gts])
    lo, hi = (np.percentile(valid, [2, 98]) if len(valid) else (0.0, 0.1)).tolist()
    columns, scales = [[_label(im, f"frame {i}") for i, im in zip(idx, rgbs)]], {}
    for label, path in models.items():
        model = DepthModel(path, threads=2)
        scales[label] = model.metric_scale or 1.0
        columns.append([_label(colour_depth(scales[label] * model.predict(im, seq.camera), lo, hi), label)
                        for im in rgbs])
    columns.append([_label(colour_depth(g, lo, hi), "true") for g in gts])
    img = np.concatenate([np.concatenate(row, axis=1) for row in zip(*columns)], axis=0)
    write_png(out, cv2.resize(img, None, fx=2, fy=2, interpolation=cv2.INTER_NEAREST))
    return {"frames": idx, "range_m": [lo, hi], "figure": out.name, "scales": scales}


def mesh_renders(mesh_path: Path, out_stem: Path, size: int, near: np.ndarray | None = None,
                 margin: float = 0.03) -> list[str]:
    """Render ``mesh_path`` from three viewpoints into ``OUT_STEM_VIEW.png``; with ``near`` (N, 3)
    points, only the part of the mesh within ``margin`` metres of their bounding box. Returns the
    file names (none when the mesh is missing or empty)."""
    if not mesh_path.is_file():
        return []
    mesh = o3d.io.read_triangle_mesh(str(mesh_path))
    if near is not None and len(near):
        mesh = crop_near(mesh, near, margin)
    names = []
    for view, img in render_views(mesh, size):
        path = out_stem.parent / f"{out_stem.name}_{view}.png"
        write_png(path, img)
        names.append(path.name)
    return names


def mask_overlay(rgb: np.ndarray, mask: np.ndarray, out: Path, side: int = 512) -> str:
    """``rgb`` (H, W, 3) uint8 with what lies outside the tissue ``mask`` (H, W bool, True =
    tissue) tinted magenta and the mask's outline in yellow, enlarged by a whole factor towards
    ``side`` pixels on the longer side; returns the file name."""
    scale = max(1, round(side / max(mask.shape)))
    img = rgb.astype(np.float32)
    img[~mask] = 0.45 * img[~mask] + 0.55 * np.array([255.0, 0.0, 255.0])
    img = cv2.resize(img.clip(0, 255).astype(np.uint8), None, fx=scale, fy=scale, interpolation=cv2.INTER_NEAREST)
    big = cv2.resize(mask.astype(np.uint8), None, fx=scale, fy=scale, interpolation=cv2.INTER_NEAREST)
    contours, _ = cv2.findContours(big, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    cv2.drawContours(img, contours, -1, (255, 230, 0), 2)
    write_png(out, img)
    return out.name


#: RGB colour of each frame label of :func:`frame_strip` (others: grey shades)
STRIP_COLOURS = {"registered": (46, 160, 67), "ok": (46, 160, 67), "extended": (46, 160, 67),
                 "keyframe": (20, 100, 40), "attached": (120, 200, 120), "rejoined": (60, 140, 220),
                 "lone": (230, 160, 40), "lost": (200, 50, 50), "not registered": (200, 50, 50),
                 "black": (30, 30, 30), "saturated": (235, 235, 190), "featureless": (170, 110, 40),
                 "unreadable": (120, 0, 0), "blurred": (140, 90, 210), "dark": (70, 70, 130),
                 "washed_out": (250, 215, 110), "duplicate": (110, 190, 230), "covered": (210, 100, 170)}


def frame_strip(labels: list[str], out: Path, width: int = 900, height: int = 26) -> dict:
    """A strip of ``labels`` (one per frame, in order: a timeline; or grouped: the counts), each
    frame an equal share of ``width`` pixels in its label's colour (:data:`STRIP_COLOURS`), with a
    legend of the counts below. Returns the file name and the counts."""
    counts: dict[str, int] = {}
    for lab in labels:
        counts[lab] = counts.get(lab, 0) + 1
    others = iter([(150, 150, 150), (110, 110, 110), (190, 190, 190), (80, 80, 80)] * 8)
    colours = {lab: STRIP_COLOURS.get(lab) or next(others) for lab in counts}
    img = np.full((height + 26, width, 3), 255, np.uint8)
    edges = np.linspace(0, width, len(labels) + 1).round().astype(int)
    for lab, x0, x1 in zip(labels, edges[:-1], edges[1:]):
        img[:height, x0:max(x1, x0 + 1)] = colours[lab]
    x = 4
    for lab, n in counts.items():
        img[height + 8:height + 20, x:x + 12] = colours[lab]
        text = f"{lab} {n}"
        cv2.putText(img, text, (x + 16, height + 19), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (30, 30, 30), 1, cv2.LINE_AA)
        x += 24 + cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, 0.4, 1)[0][0]
    write_png(out, img)
    return {"figure": out.name, "counts": counts}
