"""Convert a published data set into the project's sequence layout (docs/datasets.md, Sequence layout).

    python -m datamodules convert {uts,simcol3d,c3vd,colon10k} SRC --out DST

Every sequence found under SRC (the data set's folder as published, or any folder above
whole sequences) becomes ``DST/<name>/``: ``rgb/`` (PNG), ``depth/`` (uint16 at the data
set's native resolution, recorded as ``depth_scale`` in ``camera.json``), ``camera.json``,
``poses.txt`` (TUM, camera-to-world, metres) and ``mesh.ply`` (metres) where the data set has
them, with ``mesh_observed.txt`` (one ``1`` observed / ``0`` never observed a line, per
triangle of mesh.ply: :mod:`c3f_slam.coverage.dataset_truth`) where the data set flags which
faces its frames saw (C3VD's coverage_mesh.obj). Frames are full size: no crop or resize
(C3VD's are undistorted to their pinhole camera, as the loader reads them). The releases give no frame
times: timestamps are the frame position / 30 s.

Every sequence is opened (pose files parsed, files listed, first frame decoded) before
anything is written; each one is written into a hidden sibling folder and moved into place
when complete, so an error or an interruption never leaves a half-written sequence in DST.
An existing ``DST/<name>`` is only replaced with ``overwrite``.
"""

from __future__ import annotations

import shutil
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from c3f_core.atomic import move_into_place, staging_dir
from c3f_core.errors import InputError
from c3f_slam.coverage.dataset_truth import FLAGS_FILE, write_observed_flags
from c3f_slam.io import SequenceWriter
from datamodules.formats import PUBLISHED, PublishedSequence, find_sequences, make_format

NOMINAL_FPS = 30.0


@dataclass(kw_only=True)
class Converted:
    """What one converted sequence holds."""

    name: str
    path: Path
    frames: int
    depth: bool
    poses: bool
    mesh: bool
    depth_dropped: int  # depth pixels beyond the uint16 range at the native scale, written as 0
    seconds: float

    def summary(self) -> str:
        parts = [f"{self.frames} frames", "depth" if self.depth else "no depth", "poses" if self.poses else "no poses"]
        if self.mesh:
            parts.append("mesh")
        if self.depth_dropped:
            parts.append(f"{self.depth_dropped} depth pixels beyond the encoding range set to 0")
        return f"{self.name}: {', '.join(parts)} -> {self.path} ({self.seconds:.1f} s)"


def open_all(dataset: str, src: str | Path, only: list[str] | None = None, **options) -> dict[str, PublishedSequence]:
    """Open every sequence of ``dataset`` under ``src`` (or the named ones), checking their files."""
    if dataset not in PUBLISHED:
        raise InputError(f"data set: unknown {dataset!r} (choose from {', '.join(PUBLISHED)})")
    fmt = make_format(dataset, **options)
    found = find_sequences(fmt, src)
    if only:
        unknown = [n for n in only if n not in found]
        if unknown:
            raise InputError(f"--only: no sequence {unknown[0]!r} in {src} (found: {', '.join(found)})")
        found = {n: found[n] for n in only}
    return {name: fmt.open(path) for name, path in found.items()}


def convert(dataset: str, src: str | Path, out: str | Path, *, overwrite: bool = False, only: list[str] | None = None,
            progress: bool = True, report: Callable[[str], None] = print, **options) -> list[Converted]:
    """Convert the sequences of ``dataset`` under ``src`` into ``out/<name>/``; returns what was
    written. ``options`` go to the data set's reader (``fov``, ``calibration``, ``pinhole_focal``)."""
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise InputError(f"--out: {out} exists and is not a folder")
    sequences = open_all(dataset, src, only, **options)
    if not overwrite:
        taken = [n for n in sequences if (out / n).exists() and any((out / n).iterdir())]
        if taken:
            raise InputError(f"--out: {out / taken[0]} exists and is not empty (use --overwrite to replace it)")
    out.mkdir(parents=True, exist_ok=True)
    done: list[Converted] = []
    for name, seq in sequences.items():
        try:
            done.append(write_sequence(seq, out / name, progress))
        except (Exception, KeyboardInterrupt) as exc:
            what = "interrupted" if isinstance(exc, KeyboardInterrupt) else str(exc)
            raise InputError(f"{what}; {out / name} not written ({len(done)} of {len(sequences)} sequences "
                             "converted before it)") from None
        report(done[-1].summary())
    return done


def write_sequence(seq: PublishedSequence, dst: Path, progress: bool = True) -> Converted:
    """Write one sequence into ``dst`` (a hidden sibling first, moved into place at the end)."""
    from tqdm import tqdm

    t0 = time.perf_counter()
    tmp = staging_dir(dst)
    dropped = 0
    try:
        writer = SequenceWriter(tmp, seq.camera)
        limit = np.iinfo(np.uint16).max / seq.camera.depth_scale
        for i in tqdm(range(len(seq)), desc=f"converting {seq.name}", unit="frame", disable=not progress, leave=False):
            depth = seq.read_depth(i) if seq.has_depth else None
            if depth is not None:
                far = depth > limit
                dropped += int(far.sum())
                depth = np.where(far, 0.0, depth)
            writer.write_frame(i, seq.read_rgb(i), depth)
        mesh = seq.read_mesh()
        if mesh is not None:
            _write_mesh(tmp / "mesh.ply", *mesh)
            flags = seq.read_coverage()
            if flags is not None:
                write_observed_flags(tmp / FLAGS_FILE, flags)
        stamps = np.arange(len(seq), dtype=np.float64) / NOMINAL_FPS
        writer.finish(seq.poses if seq.has_poses else None, stamps if seq.has_poses else None)
        move_into_place(tmp, dst)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return Converted(name=seq.name, path=dst, frames=len(seq), depth=seq.has_depth, poses=seq.has_poses,
                     mesh=mesh is not None, depth_dropped=dropped,
                     seconds=time.perf_counter() - t0)


def _write_mesh(path: Path, vertices: np.ndarray, triangles: np.ndarray) -> None:
    import open3d as o3d

    from c3f_slam.fusion.tsdf import write_mesh

    mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(vertices), o3d.utility.Vector3iVector(triangles))
    write_mesh(mesh, path)
