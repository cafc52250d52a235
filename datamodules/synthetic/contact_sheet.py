"""Contact sheet of a sequence: evenly spaced RGB frames with their depth maps, for a quick look."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from c3f_core.atomic import atomic_write
from c3f_core.errors import InputError
from c3f_slam.io import Sequence
from datamodules.synthetic.generate import read_event_labels
from datamodules.synthetic.nuisances import read_nuisances

#: per-frame nuisances named in a tile's caption (border and overlay are in every frame)
_CAPTION = {"motion_blur": "blur", "defocus": "defocus", "washed_out": "washed", "repeat": "repeat"}


def _depth_colour(depth: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """Depth (m) to an RGB turbo image on a log scale between lo and hi; 0 (no depth) is black."""
    valid = depth > 0
    x = np.zeros_like(depth, dtype=np.float32)
    x[valid] = (np.log(depth[valid]) - np.log(lo)) / max(np.log(hi) - np.log(lo), 1e-6)
    img = cv2.applyColorMap(np.clip(x * 255, 0, 255).astype(np.uint8), cv2.COLORMAP_TURBO)[..., ::-1]
    img[~valid] = 0
    return img


def make_contact_sheet(seq_dir: str | Path, out: str | Path, count: int = 12, cols: int = 4,
                       depth: bool = True, tile: int = 256) -> Path:
    """Write a PNG grid of ``count`` frames of ``seq_dir`` (RGB, and depth below each if present)."""
    seq = Sequence(seq_dir)
    if count < 1 or cols < 1 or tile < 16:
        raise InputError("contact sheet: count and cols must be >= 1 and tile >= 16")
    idx = np.unique(np.linspace(0, len(seq) - 1, min(count, len(seq))).round().astype(int))
    labels = read_event_labels(seq_dir)
    nuisances = read_nuisances(seq_dir)
    show_depth = depth and seq.has_depth
    depths = [seq.read_depth(i) for i in idx] if show_depth else []
    if depths:
        allv = (np.concatenate([d[d > 0] for d in depths]) if any((d > 0).any() for d in depths)
                else np.array([0.01, 0.1]))
        lo, hi = np.percentile(allv, 1), np.percentile(allv, 99)
    h = int(round(tile * seq.camera.height / seq.camera.width))
    cells = []
    for k, i in enumerate(idx):
        rgb = cv2.resize(seq.read_rgb(i), (tile, h), interpolation=cv2.INTER_AREA)
        extra = [_CAPTION[n] for n in nuisances.get(int(i), []) if n in _CAPTION]
        text = " ".join(t for t in (seq.frame_names[i], labels[i] if i < len(labels) else "", *extra) if t)
        (tw, th), _ = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, 0.4, 1)
        rgb[: th + 8, : tw + 8] //= 4  # darkened behind the caption: readable over washed-out frames and overlays
        cv2.putText(rgb, text, (4, 14), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (255, 255, 255), 1, cv2.LINE_AA)
        cell = rgb
        if depths:
            d = cv2.resize(depths[k], (tile, h), interpolation=cv2.INTER_NEAREST)
            cell = np.concatenate([rgb, _depth_colour(d, lo, hi)], axis=0)
        cells.append(cell)
    while len(cells) % cols:
        cells.append(np.zeros_like(cells[0]))
    rows = [np.concatenate(cells[r : r + cols], axis=1) for r in range(0, len(cells), cols)]
    sheet = np.concatenate(rows, axis=0)
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    with atomic_write(out) as tmp:  # an interrupted write leaves no partial image
        if not cv2.imwrite(str(tmp), cv2.cvtColor(sheet, cv2.COLOR_RGB2BGR)):
            raise InputError(f"{out}: could not write the contact sheet")
    return out
