"""The report's second step: :func:`make_figures` draws every figure of the report from the
collected :class:`~c3f_demo.report_records.ReportData` alone (PNG files in ``DIR/figures``: sample
frames beside predicted and true depth, the mesh renders, and for a user's video the tissue mask
over a frame and a strip of what became of each frame; for the demo, the 3D view's videos in the
viewed run's folder) and returns them as :class:`~c3f_demo.report_records.Figures`. Depths in
metres (the colour bar is labelled in cm)."""

from __future__ import annotations

from itertools import chain
from pathlib import Path

import cv2
import numpy as np
import open3d as o3d

from c3f_core.atomic import atomic_write
from c3f_core.errors import InputError
from c3f_demo.render import crop_near, render_views
from c3f_demo.report_records import DepthSamples, Figures, Image, ReportData, TissueSample, Video, ViewData, ViewFigures


def make_figures(data: ReportData, root: Path) -> Figures:
    """Every figure of the report drawn from ``data`` into ``root/figures`` (the demo's 3D view
    into its run folder), with the images earlier stages drew (``data.images``)."""
    out, size = root / "figures", data.config["report"]["render_size"]
    depth = depth_samples(data.depth_samples, out / "depth_samples.png") if data.depth_samples else {}
    meshes = {n: mesh_renders(m, out / f"mesh_{n}", size) for n, m in data.meshes.items()}
    coverage = {n: mesh_renders(m, out / f"coverage_{n}", size, near=data.path_points)
                for n, m in data.coverage.items()}
    tissue = tissue_figure(data.tissue, out) if data.tissue else None
    frames = frame_figures(data.frame_labels, out)
    drawn = [depth.get("figure"), *chain(*meshes.values(), *coverage.values()), (tissue or {}).get("figure"),
             *(f["figure"] for f in frames.values())]
    images = {**data.images, **{f"figures/{n}": Image.read(root, f"figures/{n}") for n in drawn if n}}
    return Figures(images=images, depth=depth, meshes=meshes, coverage=coverage, tissue=tissue, frames=frames,
                   view=view_figures(data.view, root))


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


def depth_samples(samples: DepthSamples, out: Path) -> dict:
    """Rows of [frame | predicted depth of each model | true depth] of the sample frames, one
    colour range (the true depth's 2nd-98th percentile over those frames). Returns the frames, the
    range, the file name and the models' scales."""
    valid = np.concatenate([g[g > 0] for g in samples.true])
    lo, hi = (np.percentile(valid, [2, 98]) if len(valid) else (0.0, 0.1)).tolist()
    columns = [[_label(im, f"frame {i}") for i, im in zip(samples.frames, samples.rgb)]]
    columns += [[_label(colour_depth(d, lo, hi), label) for d in depths] for label, depths in samples.predicted.items()]
    columns.append([_label(colour_depth(g, lo, hi), "true") for g in samples.true])
    img = np.concatenate([np.concatenate(row, axis=1) for row in zip(*columns)], axis=0)
    write_png(out, cv2.resize(img, None, fx=2, fy=2, interpolation=cv2.INTER_NEAREST))
    return {"frames": samples.frames, "range_m": [lo, hi], "figure": out.name, "scales": samples.scales}


def mesh_renders(mesh: o3d.geometry.TriangleMesh | None, out_stem: Path, size: int, near: np.ndarray | None = None,
                 margin: float = 0.03) -> list[str]:
    """Render ``mesh`` (left as it is) from three viewpoints into ``OUT_STEM_VIEW.png``; with ``near``
    (N, 3) points, only the part of the mesh within ``margin`` metres of their bounding box.
    Returns the file names (none when there is no mesh or it is empty)."""
    if mesh is None:
        return []
    mesh = crop_near(mesh, near, margin) if near is not None and len(near) else o3d.geometry.TriangleMesh(mesh)
    names = []
    for view, img in render_views(mesh, size):
        path = out_stem.parent / f"{out_stem.name}_{view}.png"
        write_png(path, img)
        names.append(path.name)
    return names


def tissue_figure(sample: TissueSample, out: Path) -> dict:
    """The tissue mask drawn over its frame (:func:`mask_overlay`, ``OUT/tissue_mask.png``)."""
    return {"run": sample.run, "frame": sample.frame,
            "figure": mask_overlay(sample.rgb, sample.mask, out / "tissue_mask.png")}


def frame_figures(labels: dict[str, tuple[str, list[str]]], out: Path) -> dict[str, dict]:
    """Per configuration, the strip of its frames' labels (:func:`frame_strip`, ``OUT/frames_NAME.png``)
    and its kind (``timeline`` or ``counts``)."""
    return {name: {"kind": kind, **frame_strip(labs, out / f"frames_{name}.png")}
            for name, (kind, labs) in labels.items()}


def view_figures(view: ViewData | None, root: Path) -> ViewFigures:
    """The 3D view's videos: those the ``view`` stage wrote (or its error), or for the demo,
    :func:`c3f_slam.view.build.write_view` of the run folder (view.html and the videos, with the
    render time per frame of each)."""
    from c3f_slam.view.build import CAPTIONS, write_view

    if view is None or view.error or not view.write:
        return ViewFigures() if view is None else ViewFigures(view.videos, error=view.error)
    try:
        made = write_view(root / view.folder, progress=False).videos
    except InputError as exc:
        return ViewFigures(error=str(exc))
    videos = tuple(Video.read(root, f"{view.folder}/{v}", f"{v}: {CAPTIONS[v]}") for v in made)
    return ViewFigures(videos, {v: r["ms_per_frame"] for v, r in made.items() if "ms_per_frame" in r})


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
