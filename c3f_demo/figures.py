"""Figures of the demo report (PNG files in ``DIR/figures``): sample frames beside predicted and
true depth, and the mesh renders. Depths in metres (the colour bar is labelled in cm)."""

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
