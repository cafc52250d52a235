"""Run outputs of the SLAM runtime, every file written atomically.

Layout of an output folder (:class:`RunOutputs`)::

    OUT/
      trajectory.txt        TUM, camera-to-world, metres, registered frames only
      summary.json          settings, counts, timings, metrics (JSON; NaN written as null)
      keyframe_graph.json   keyframes (frame, timestamp, position, fragment, lone) and edges
      keyframe_graph.png    top view (x vs z, cm) of the keyframe graph
      mesh.ply              fused mesh (written with c3f_slam.fusion.tsdf.write_mesh)
      trajectory.png        estimate vs ground truth (c3f_slam.evaluation.trajectory_plot.plot_trajectories)
      coverage.ply          ground-truth mesh painted seen / unseen (evaluate)
      coverage.json         unseen share of the wall, overall and per segment (c3f_slam.pipeline.coverage_stage)
      coverage_map.png      the unrolled wall, unseen parts flagged
      unseen.ply            mesh.ply with the unseen wall added as painted patches
      components/NN/        a component not joined to the main map (c3f_slam.pipeline.components):
                            trajectory.txt and mesh.ply in its own world frame

A run folder holds one run: ``c3f_slam run`` builds it in a hidden sibling
(``.OUT.partial-XXXX``) and moves it into place when the run ends, successfully or not
(:class:`RunFolder`), so OUT is never a mix of two runs; a run killed before that leaves the
previous OUT as it was. A complete earlier run is replaced only when asked (``--overwrite``).
summary.json's ``status`` says whether the run completed (``ok``) or not (``error``, with the
frames done so far); ``evaluate`` refuses runs that did not complete.
"""

from __future__ import annotations

import json
import math
import shutil
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from c3f_core.atomic import atomic_write, atomic_write_text, move_into_place, staging_dir
from c3f_core.errors import InputError
from c3f_slam.io.tum import write_tum
from c3f_slam.posegraph import PoseGraph

COMPONENTS_DIR = "components"  #: folder of the components beside the main map (RunOutputs.component)


def to_jsonable(obj):
    """Numpy scalars/arrays to Python, NaN/inf to None, Paths to str, recursively."""
    if isinstance(obj, dict):
        return {str(k): to_jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [to_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return to_jsonable(obj.tolist())
    if isinstance(obj, (np.bool_, bool)):
        return bool(obj)
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        v = float(obj)
        return v if math.isfinite(v) else None
    if isinstance(obj, Path):
        return str(obj)
    return obj


def write_json(path: str | Path, data: dict) -> None:
    """Write ``data`` as indented JSON atomically (strict JSON: no NaN)."""
    atomic_write_text(path, json.dumps(to_jsonable(data), indent=2, allow_nan=False) + "\n")


def write_trajectory(
    path: str | Path, stamps: np.ndarray, poses: np.ndarray, registered: np.ndarray | None = None
) -> int:
    """Write the registered camera-to-world poses as TUM; returns the number of lines written.

    ``registered``: boolean mask over frames (default: every pose that is finite).
    """
    stamps = np.asarray(stamps, dtype=np.float64)
    poses = np.asarray(poses, dtype=np.float64).reshape(-1, 4, 4)
    if len(stamps) != len(poses):
        raise ValueError(f"{len(stamps)} timestamps for {len(poses)} poses")
    mask = np.all(np.isfinite(poses), axis=(1, 2))
    if registered is not None:
        mask &= np.asarray(registered, dtype=bool)
    write_tum(path, stamps[mask], poses[mask])
    return int(mask.sum())


@dataclass
class GraphNode:
    """A keyframe: node id, its frame index and timestamp, world position (m), fragment, lone flag."""

    id: int
    frame: int
    timestamp: float
    position: list[float]
    fragment: int | None = None
    lone: bool = False


@dataclass
class GraphEdge:
    """Constraint between keyframe nodes i and j (p_i = T_ij p_j)."""

    i: int
    j: int
    kind: str = "loop"
    n_matches: int = 0
    pruned: bool = False
    rms_m: float | None = None


@dataclass
class KeyframeGraph:
    nodes: list[GraphNode] = field(default_factory=list)
    edges: list[GraphEdge] = field(default_factory=list)

    def to_dict(self) -> dict:
        return {
            "convention": "positions are camera centres in the world frame (metres); edge (i, j) "
            "constrains p_i = T_ij p_j",
            "nodes": [asdict(n) for n in self.nodes],
            "edges": [asdict(e) for e in self.edges],
        }

    @classmethod
    def from_posegraph(
        cls,
        graph: PoseGraph,
        frames: list[int],
        timestamps: list[float] | None = None,
        lone: set[int] | None = None,
        fragments: list[int] | None = None,
    ) -> KeyframeGraph:
        """Nodes and edges of a (global) :class:`PoseGraph`; ``frames[k]`` is node k's frame."""
        if len(frames) != graph.n_nodes:
            raise ValueError(f"{len(frames)} frame ids for {graph.n_nodes} nodes")
        P = graph.poses
        rms = graph.edge_rms()
        nodes = [
            GraphNode(
                k,
                int(frames[k]),
                float(timestamps[k]) if timestamps is not None else float(frames[k]),
                [float(x) for x in P[k, :3, 3]],
                None if fragments is None else int(fragments[k]),
                bool(lone and k in lone),
            )
            for k in range(graph.n_nodes)
        ]
        edges = [
            GraphEdge(e.i, e.j, e.kind, int(round(e.n_correspondences)), e.pruned, float(rms[k]))
            for k, e in enumerate(graph.edges)
        ]
        return cls(nodes, edges)


def draw_keyframe_graph(path: str | Path, graph: KeyframeGraph, title: str = "keyframe graph") -> None:
    """PNG top view (x vs z, cm) of keyframes and their edges, drawn with matplotlib only.

    Odometry edges grey, loop edges blue, edges across tracking breaks (rejoin) green, dense
    fallback edges orange, pruned edges dashed red; lone keyframes hollow.
    """
    from matplotlib.collections import LineCollection
    from matplotlib.figure import Figure

    fig = Figure(figsize=(7, 6), dpi=100)
    ax = fig.add_subplot(1, 1, 1)
    pos = {n.id: np.asarray(n.position) * 100.0 for n in graph.nodes}
    styles = {"odometry": dict(color="0.5", lw=1.0, ls="-"), "loop": dict(color="tab:blue", lw=0.8, ls="-"),
              "rejoin": dict(color="tab:green", lw=1.2, ls="-"),
              "fallback": dict(color="tab:orange", lw=1.2, ls="-")}
    # one LineCollection per style (a plot call per edge takes minutes on big graphs)
    pruned_style = dict(color="tab:red", lw=0.8, ls="--")
    groups: dict[str, list] = {}
    for e in graph.edges:
        if e.i not in pos or e.j not in pos:
            continue
        key = "pruned" if e.pruned else (e.kind if e.kind in styles else "loop")
        a, b = pos[e.i], pos[e.j]
        groups.setdefault(key, []).append([(a[0], a[2]), (b[0], b[2])])
    for key, segs in groups.items():
        st = pruned_style if key == "pruned" else styles[key]
        ax.add_collection(LineCollection(segs, colors=st["color"], linewidths=st["lw"], linestyles=st["ls"],
                                         zorder=1))
    if graph.nodes:
        P = np.array([pos[n.id] for n in graph.nodes])
        lone = np.array([n.lone for n in graph.nodes])
        ax.scatter(P[~lone, 0], P[~lone, 2], s=18, c="k", zorder=2, label="keyframe")
        if lone.any():
            ax.scatter(P[lone, 0], P[lone, 2], s=24, facecolors="none", edgecolors="tab:orange", zorder=2,
                       label="lone keyframe")
        if len(graph.nodes) <= 60:
            for n in graph.nodes:
                ax.annotate(str(n.frame), (pos[n.id][0], pos[n.id][2]), fontsize=6, xytext=(2, 2),
                            textcoords="offset points")
        ax.legend(loc="best", fontsize=8)
    ax.set_xlabel("x [cm]")
    ax.set_ylabel("z [cm]")
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(True, lw=0.3)
    ax.set_title(f"{title}: {len(graph.nodes)} keyframes, {len(graph.edges)} edges, "
                 f"{sum(e.pruned for e in graph.edges)} pruned", fontsize=9)
    fig.tight_layout()
    with atomic_write(Path(path), suffix=".png") as tmp:
        fig.savefig(tmp, format="png")


def run_status(folder: Path) -> str | None:
    """``status`` of the run in ``folder`` (its summary.json), None when it holds no readable summary."""
    try:
        return str(json.loads((folder / "summary.json").read_text()).get("status"))
    except (OSError, ValueError, AttributeError):
        return None


class RunFolder:
    """Where one run is built (:attr:`staging`) and the folder it becomes (:attr:`target`).

    :meth:`claim` checks ``target`` before anything is written: it may be missing or empty,
    or hold an earlier run: a complete one (status ``ok``) only with ``overwrite``, an
    incomplete one always. A non-empty folder that is not a run folder is never replaced.
    """

    def __init__(self, target: str | Path, overwrite: bool = False) -> None:
        self.target = Path(target)
        self.overwrite = overwrite
        self.staging: Path | None = None

    def claim(self) -> Path:
        """InputError (one line, nothing written) unless the run may go into ``target``;
        returns the staging folder to write into."""
        t = self.target
        if t.exists() and not t.is_dir():
            raise InputError(f"--out {t}: exists and is not a folder")
        if t.is_dir() and any(t.iterdir()):
            status = run_status(t)
            if status is None:
                raise InputError(f"--out {t}: not empty and not a run folder (no summary.json); choose another --out")
            if status == "ok" and not self.overwrite:
                raise InputError(f"--out {t}: holds a complete run (summary.json status ok); "
                                 "pass --overwrite to replace it, or choose another --out")
        self.staging = staging_dir(t, "partial")
        return self.staging

    def holds_complete_run(self) -> bool:
        """``target`` holds a complete earlier run (summary.json status ``ok``)."""
        return self.target.is_dir() and run_status(self.target) == "ok"

    def discard(self) -> None:
        """Delete the built run; ``target`` stays as it was."""
        if self.staging is not None:
            shutil.rmtree(self.staging, ignore_errors=True)
            self.staging = None

    def publish(self) -> None:
        """Move the built run into ``target`` (the earlier contents are deleted once it is there)."""
        if self.staging is not None:
            move_into_place(self.staging, self.target)
            self.staging = None


class FrameLog:
    """``frame_log.csv`` of a run, written as the frames come (memory stays flat however long the
    video): per frame streamed, its index, timestamp (s) and what happened to it (a skip reason, or
    the back-end's decision kind). The run folder is published whole, so a line is never seen half
    written."""

    HEADER = "index,timestamp,outcome"

    def __init__(self, path: str | Path) -> None:
        self.file = open(path, "w", encoding="utf-8")  # noqa: SIM115 - closed by close()
        self.file.write(self.HEADER + "\n")

    def write(self, index: int, timestamp: float, outcome: str) -> None:
        self.file.write(f"{index},{timestamp:.6f},{outcome}\n")

    def close(self) -> None:
        if not self.file.closed:
            self.file.close()

    @staticmethod
    def read(path: str | Path) -> dict[int, str]:
        """Frame index -> outcome of a ``frame_log.csv`` (empty without the file)."""
        path = Path(path)
        if not path.is_file():
            return {}
        rows = path.read_text(encoding="utf-8").splitlines()[1:]
        return {int(index): outcome for index, _, outcome in (row.split(",", 2) for row in rows if row)}


class RunOutputs:
    """The files of one runtime run in ``root`` (created on first write)."""

    def __init__(self, root: str | Path) -> None:
        self.root = Path(root)

    @property
    def trajectory(self) -> Path:
        return self.root / "trajectory.txt"

    @property
    def summary(self) -> Path:
        return self.root / "summary.json"

    @property
    def graph_json(self) -> Path:
        return self.root / "keyframe_graph.json"

    @property
    def graph_png(self) -> Path:
        return self.root / "keyframe_graph.png"

    @property
    def mesh(self) -> Path:
        return self.root / "mesh.ply"

    @property
    def trajectory_png(self) -> Path:
        return self.root / "trajectory.png"

    @property
    def coverage_mesh(self) -> Path:
        return self.root / "coverage.ply"

    @property
    def coverage_json(self) -> Path:
        return self.root / "coverage.json"

    @property
    def coverage_png(self) -> Path:
        return self.root / "coverage_map.png"

    @property
    def unseen_mesh(self) -> Path:
        return self.root / "unseen.ply"

    @property
    def coverage_mask(self) -> Path:
        return self.root / "coverage_mask.png"

    @property
    def tissue_mask(self) -> Path:
        return self.root / "tissue_mask.png"

    def component(self, n: int) -> RunOutputs:
        """The files of component ``n`` (>= 1) beside the main map: ``components/NN/``."""
        return RunOutputs(self.root / COMPONENTS_DIR / f"{n:02d}")

    def write_trajectory(self, stamps: np.ndarray, poses: np.ndarray, registered: np.ndarray | None = None) -> int:
        return write_trajectory(self.trajectory, stamps, poses, registered)

    @property
    def frame_log(self) -> Path:
        return self.root / "frame_log.csv"

    def write_summary(self, summary: dict) -> None:
        write_json(self.summary, summary)

    def write_graph(self, graph: KeyframeGraph, draw: bool = True) -> None:
        write_json(self.graph_json, graph.to_dict())
        if draw:
            draw_keyframe_graph(self.graph_png, graph)
