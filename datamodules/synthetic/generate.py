"""Generate a whole sequence: build the colon, plan the path, render, write the layout.

Output (docs/datasets.md, Sequence layout; via :class:`c3f_slam.io.SequenceWriter`)::

    OUT/
      rgb/NNNNNN.png      uint8 RGB
      depth/NNNNNN.png    uint16, camera.depth_scale units per metre (exact ray-cast depth)
      camera.json         intrinsics (pinhole, no distortion)
      poses.txt           TUM, camera-to-world, metres, timestamps = index / fps
      mesh.ply            the ground-truth mesh the depth was ray cast against
      params.json         seed and every parameter (``generate --config params.json`` replays it)
      frames.csv          per frame: time, arc length, event label (the event's frames and
                          its ramps in and out), wall distance
      nuisances.json      only with nuisance.* on: frame index -> the nuisances of that frame
      tissue_mask.png     only with nuisance.border: uint8, 255 = tissue (depth is 0 elsewhere)

Nuisances of real recordings (``SimParams.nuisance``, :mod:`datamodules.synthetic.nuisances`) are
applied to the rendered frames of this layout only; a repeated frame carries the pose and depth
of the frame it repeats (poses.txt), while frames.csv keeps the planned path. With every nuisance
off the files are exactly those of the simulator without them (params.json has no ``nuisance``
group while it holds the defaults).

The sequence is written into a hidden sibling folder and renamed to OUT at the end, so an
interrupted run never leaves a half sequence under OUT; an existing non-empty OUT is only
replaced with ``overwrite=True``. Parameters are checked when they are made (frozen
:class:`~datamodules.synthetic.params.SimParams`), before anything is written.
"""

from __future__ import annotations

import csv
import json
import shutil
from collections import deque
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path

import numpy as np
import open3d as o3d

from c3f_core.atomic import move_into_place, staging_dir
from c3f_slam.io import SequenceWriter
from datamodules.synthetic.layouts import layout_writer
from datamodules.synthetic.nuisances import NuisanceChain
from datamodules.synthetic.params import (
    PAPER_COMMON,
    PAPER_TABLE,
    NuisanceParams,
    SimParams,
    check_layout,
    check_output,
)
from datamodules.synthetic.scene import SimScene, build_scene, render_frames

FORMAT_VERSION = 1
__all__ = ["generate_sequence", "read_event_labels"]


def params_record(scene: SimScene) -> dict:
    p = scene.params
    c = scene.colon
    return {
        "generator": "datamodules.synthetic",
        "format_version": FORMAT_VERSION,
        "seed": p.seed,
        "preset": p.preset,
        "params": _params_dict(p),
        "paper_table": dict(PAPER_TABLE[p.preset], **PAPER_COMMON) if p.preset in PAPER_TABLE else None,
        "units": "metres, radians inside the code; params: lengths in m, angles in degrees",
        "camera": scene.camera.to_dict(),
        "mesh": {"vertices": int(len(c.vertices)), "triangles": int(len(c.triangles)), "length_m": c.length},
        "folds": [{"s": f.s, "sigma": f.sigma, "heights": list(f.heights)} for f in c.folds],
        "polyps": [{"s": q.s, "theta": q.theta, "radius": q.radius, "height": q.height} for q in c.polyps],
        "events": {k: int(sum(1 for x in scene.path.labels if x == k))
                   for k in ("closeup", "burst", "occluded", "roll")},
    }


def _params_dict(p: SimParams) -> dict:
    """Every parameter; the ``nuisance`` group only when it differs from the defaults (so
    sequences without nuisances keep the params.json of the simulator before them)."""
    d = p.to_dict()
    if p.nuisance == NuisanceParams():
        d.pop("nuisance")
    return d


def generate_sequence(
    params: SimParams,
    out: str | Path,
    *,
    overwrite: bool = False,
    progress: bool = True,
    layout: str = "c3f",
    on_frame: Callable[[int], None] | None = None,
) -> Path:
    """Render ``params`` into the folder ``out``; returns its path.

    ``layout``: ``c3f`` (the project's own, docs/datasets.md) or, additionally written from the
    same frames, ``uts`` / ``simcol3d`` / ``c3vd`` / ``colon10k`` (see :mod:`datamodules.synthetic.layouts`).
    """
    layout = check_layout(layout)
    out = check_output(out, overwrite).resolve()
    tmp = staging_dir(out)
    try:
        scene = build_scene(params)
        _write_all(scene, tmp, layout, progress, on_frame)
        move_into_place(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return out


def _write_all(scene: SimScene, root: Path, layout: str, progress: bool,
               on_frame: Callable[[int], None] | None) -> None:
    from tqdm import tqdm

    p = scene.params
    writer = SequenceWriter(root, scene.camera)
    extra = None
    if layout != "c3f":
        extra = layout_writer(layout, root / layout, scene)
    chain = NuisanceChain(p.nuisance, p.camera.width, p.camera.height, p.path.fps, p.seed) if p.nuisance.active() \
        else None
    poses = scene.path.poses.copy()  # a repeated frame carries the pose of the frame it repeats
    names: dict[int, tuple[str, ...]] = {}
    pending: deque[Future] = deque()
    with ThreadPoolExecutor(max_workers=1) as pool:  # PNG encoding overlaps the next frame's rendering
        bar = tqdm(total=p.path.frames, desc=f"simulating {root.name.split('.partial-')[0].lstrip('.')}",
                   unit="frame", disable=not progress, leave=False)
        try:
            for i, rgb, depth in render_frames(scene):
                if chain is None:
                    pending.append(pool.submit(writer.write_frame, i, rgb, depth))
                else:
                    f = chain.apply(i, rgb, depth)
                    poses[i], names[i] = scene.path.poses[f.source], f.names
                    pending.append(pool.submit(writer.write_frame, i, f.rgb, f.depth))
                if extra is not None:  # the published layouts get the frames as rendered
                    pending.append(pool.submit(extra.write_frame, i, rgb, depth))
                while len(pending) > 4:
                    pending.popleft().result()
                bar.update(1)
                if on_frame is not None:
                    on_frame(i)
            while pending:
                pending.popleft().result()
        finally:
            bar.close()
    o3d.io.write_triangle_mesh(str(root / "mesh.ply"), scene.colon.to_legacy_mesh(), write_ascii=False,
                               compressed=False, write_vertex_normals=False, write_vertex_colors=False,
                               write_triangle_uvs=False, print_progress=False)
    (root / "params.json").write_text(json.dumps(params_record(scene), indent=2, sort_keys=True) + "\n")
    _write_frames_csv(scene, root / "frames.csv")
    if chain is not None:
        chain.write_truth(root, names)
    if extra is not None:
        extra.finish()
    stamps = np.arange(p.path.frames, dtype=np.float64) / p.path.fps
    writer.finish(poses, stamps)


def _write_frames_csv(scene: SimScene, path: Path) -> None:
    fps = scene.params.path.fps
    lines = ["index,timestamp,s_m,event,wall_distance_mm"]
    for i, (s, label, d) in enumerate(zip(scene.path.controls.s, scene.path.labels, scene.path.wall_distance)):
        lines.append(f"{i},{i / fps:.6f},{s:.6f},{label},{d * 1000:.3f}")
    path.write_text("\n".join(lines) + "\n")


def read_event_labels(root: str | Path) -> list[str]:
    """Per-frame event labels of a generated sequence (frames.csv ``event`` column, in frame
    order; '' = a plain frame); an empty list when the folder has no frames.csv."""
    path = Path(root) / "frames.csv"
    if not path.is_file():
        return []
    with path.open(newline="") as fh:
        rows = sorted(csv.DictReader(fh), key=lambda r: int(r["index"]))
    return [r.get("event") or "" for r in rows]
