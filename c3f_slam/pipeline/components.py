"""The parts of a run that could not be joined: every connected component of the map, and
the files of the large ones (``OUT/components/NN/``).

When tracking breaks and re-joining fails, the keyframe graph splits into components. The
**main map** is the component with the most registered frames (ties: the one with the
oldest keyframe); it is written as ``OUT/trajectory.txt`` and ``OUT/mesh.ply``. Every other
component with at least ``components.min_frames`` frames (at most ``components.max_written``
of them, the largest) is optimised on its own (:meth:`FragmentSlam.finish`), fused with the
same TSDF settings and written to ``OUT/components/NN/`` (``trajectory.txt``, TUM,
camera-to-world, metres, in the component's own world frame: its oldest keyframe's; and
``mesh.ply``). ``NN`` is the component's id: 0 is the main map, then 1, 2, ... by frames.
summary.json's ``components`` lists them all (:func:`component_summary`), so a user sees which
part of the procedure is missing instead of silently losing it.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from open3d.geometry import TriangleMesh

from c3f_slam.config import ComponentConfig
from c3f_slam.evaluation.trajectory import path_length
from c3f_slam.fusion.tsdf import write_mesh
from c3f_slam.io.run_outputs import RunOutputs


@dataclass
class MapComponent:
    """One connected component of the map: its frames (log ``rows``, stream order) with
    their camera-to-world ``poses`` (n, 4, 4, metres, in the component's own world frame),
    the ``fragments`` they belong to (fusion) and its number of ``keyframes``."""

    rows: np.ndarray
    poses: np.ndarray
    fragments: frozenset[int]
    keyframes: int

    @property
    def frames(self) -> int:
        return len(self.rows)

    def pose_of(self, row: int) -> np.ndarray | None:
        """Pose of log row ``row`` (None when the frame is not in this component)."""
        k = int(np.searchsorted(self.rows, row))
        return self.poses[k] if k < len(self.rows) and self.rows[k] == row else None


@dataclass
class ComponentEntry:
    """A component with its id (0: the main map), where it is written (None: not written)
    and why not."""

    id: int
    component: MapComponent
    outputs: RunOutputs | None
    not_written: str | None = None

    @property
    def main(self) -> bool:
        return self.id == 0


def plan_components(components: list[MapComponent], cfg: ComponentConfig, outputs: RunOutputs) -> list[ComponentEntry]:
    """Ids and destinations of ``components`` (the main map first, then by frames, as the
    back-ends return them): the main map goes to ``outputs``, a component with a rule of
    :meth:`ComponentConfig.writes` against it nowhere."""
    entries = []
    for k, comp in enumerate(components):
        why = None if k == 0 else cfg.writes(comp.frames, k)
        dest = outputs if k == 0 else (None if why else outputs.component(k))
        entries.append(ComponentEntry(k, comp, dest, why))
    return entries


def write_components(entries: list[ComponentEntry], stamps: np.ndarray,
                     fuse: Callable[[MapComponent], TriangleMesh] | None) -> None:
    """Write each component other than the main map that has a destination: its trajectory
    (timestamps ``stamps`` per log row) and, with ``fuse`` (None: no fusion), its mesh."""
    for e in entries:
        if e.main or e.outputs is None:
            continue
        comp = e.component
        e.outputs.write_trajectory(stamps[comp.rows], comp.poses)
        if fuse is not None:
            mesh = fuse(comp)
            if len(mesh.triangles):
                write_mesh(mesh, e.outputs.mesh)


def component_summary(entries: list[ComponentEntry], frame_index: np.ndarray, root: RunOutputs) -> list[dict]:
    """summary.json's ``components``: per component its id, ``main``, frames, first / last
    frame index (``frame_index`` per log row), keyframes, path length (metres, camera
    centres in stream order), and the files written (paths relative to the run folder
    ``root``) or why none are."""
    out = []
    for e in entries:
        comp = e.component
        files = []
        if e.outputs is not None:
            files = [p.relative_to(root.root).as_posix() for p in (e.outputs.trajectory, e.outputs.mesh)
                     if p.is_file()]
        out.append({
            "id": e.id, "main": e.main, "frames": comp.frames,
            "first_frame": int(frame_index[comp.rows[0]]), "last_frame": int(frame_index[comp.rows[-1]]),
            "keyframes": comp.keyframes, "path_length_m": path_length(comp.poses[:, :3, 3]),
            "files": files, "not_written": e.not_written,
        })
    return out
