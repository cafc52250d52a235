"""The layers of a run folder's view (:class:`c3f_slam.view.layers.Layer`), in the main map's frame.

- ``surface``: ``mesh.ply`` in its colours; ``unseen``: the patches ``unseen.ply`` paints
  :data:`c3f_slam.coverage.render.UNSEEN_COLOUR`;
- ``path``: the registered camera positions (``trajectory.txt``); ``keyframes``: each keyframe
  of the main map as its viewing pyramid (``keyframe_graph.json``, poses from the trajectory);
- with a ground-truth sequence (``--gt``, else the one ``evaluate --gt`` recorded in
  ``evaluation.json``): ``gt_path`` (true camera positions) and ``gt_surface`` (``coverage.ply``,
  the true surface painted seen green / unseen red by ``evaluate``, else the sequence's
  ``mesh.ply``; cropped to 2 cm around the path), moved into the run's frame by the inverse of
  the alignment ``evaluate`` uses for meshes (SE(3) in RGB-D mode, Sim(3) otherwise);
- ``components``: the meshes and paths of ``components/NN/``, each in its own frame (its pose
  relative to the main map is unknown), set down side by side beyond the main map along x.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import open3d as o3d

from c3f_slam.coverage.render import UNSEEN_COLOUR
from c3f_slam.evaluation.trajectory import associate, ate
from c3f_slam.io import Sequence, read_tum
from c3f_slam.io.run_outputs import RunOutputs
from c3f_slam.view.budget import ViewBudget
from c3f_slam.view.layers import Layer, frusta, mesh_layer, polyline_segments, triangles_coloured
from c3f_slam.view.raycast import crop_near

GT_MARGIN = 0.02  #: metres of the true surface kept around the true path
PATH_COLOUR, KEYFRAME_COLOUR, GT_COLOUR, COMPONENT_COLOUR = "#ffd400", "#ff8c00", "#00c853", "#c77dff"


def _read_json(path: Path) -> dict:
    return json.loads(path.read_text()) if path.is_file() else {}


def _mesh(path: Path) -> o3d.geometry.TriangleMesh | None:
    if not path.is_file():
        return None
    mesh = o3d.io.read_triangle_mesh(str(path))
    return mesh if len(mesh.triangles) else None


def map_layers(out: RunOutputs, budget: ViewBudget, summary: dict) -> list[Layer]:
    """``surface``, ``unseen``, ``path`` and ``keyframes`` of the main map."""
    layers = []
    mesh = _mesh(out.mesh)
    if mesh is not None:
        layers.append(mesh_layer("surface", "Reconstructed surface", mesh, budget.surface, "mesh.ply"))
    painted = _mesh(out.unseen_mesh)
    patches = triangles_coloured(painted, UNSEEN_COLOUR) if painted is not None else None
    if patches is not None and len(patches.triangles):
        share = summary.get("unseen_share")
        label = "Unseen wall" + (f" ({100 * share:.1f} %)" if share is not None else "")
        layers.append(mesh_layer("unseen", label, patches, budget.unseen, "unseen.ply"))
    stamps, poses = read_tum(out.trajectory) if out.trajectory.is_file() else (np.zeros(0), np.zeros((0, 4, 4)))
    if len(poses) >= 2:
        layers.append(Layer("path", f"Camera path ({len(poses)} frames)", "line", poses[:, :3, 3],
                            colour=PATH_COLOUR, note="trajectory.txt"))
    kf_stamps = [n["timestamp"] for n in _read_json(out.graph_json).get("nodes", [])]
    ie, _ = associate(stamps, np.asarray(kf_stamps, np.float64), max_dt=1e-4)
    cam = summary.get("camera")
    if len(ie) and cam:
        K = np.array([[cam["fx"], 0, cam["cx"]], [0, cam["fy"], cam["cy"]], [0, 0, 1.0]])
        depth = max(0.04 * _extent(poses[:, :3, 3]), 1e-3)
        layers.append(Layer("keyframes", f"Keyframes ({len(ie)})", "segments",
                            frusta(poses[ie], K, cam["width"], cam["height"], depth), colour=KEYFRAME_COLOUR,
                            note="keyframe_graph.json: each keyframe's viewing pyramid"))
    return layers


def _extent(points: np.ndarray) -> float:
    return float(np.linalg.norm(points.max(axis=0) - points.min(axis=0))) if len(points) else 0.0


def gt_sequence(out: RunOutputs, gt: str | Path | None) -> Path | None:
    """The ground-truth sequence: ``gt``, else the one recorded by ``evaluate --gt`` if it still exists."""
    if gt is not None:
        return Path(gt)
    recorded = _read_json(out.root / "evaluation.json").get("gt_sequence")
    return Path(recorded) if recorded and Path(recorded, "poses.txt").is_file() else None


def gt_layers(out: RunOutputs, seq_dir: Path, budget: ViewBudget, summary: dict) -> list[Layer]:
    """``gt_path`` and ``gt_surface`` moved into the run's frame (empty when nothing associates)."""
    seq = Sequence(seq_dir)
    stamps, poses = read_tum(out.trajectory)
    ie, ig = associate(stamps, seq.timestamps) if seq.has_poses else (np.zeros(0, int), np.zeros(0, int))
    if len(ie) < 3:
        return []
    align = "se3" if summary.get("depth_source", "files") == "files" else "sim3"
    a = ate(poses[ie], seq.poses[ig], align)
    to_run = np.eye(4)  # x_run = R^T (x_gt - t) / s
    to_run[:3, :3], to_run[:3, 3] = a.R.T / a.scale, -a.R.T @ a.t / a.scale
    gt_pos = seq.poses[ig][:, :3, 3]
    layers = [Layer("gt_path", "Ground-truth path", "line", gt_pos @ to_run[:3, :3].T + to_run[:3, 3],
                    colour=GT_COLOUR, note=f"{seq_dir}/poses.txt, aligned {align.upper()}")]
    source = out.coverage_mesh if out.coverage_mesh.is_file() else seq.mesh_path
    mesh = _mesh(Path(source)) if source is not None else None
    if mesh is not None:
        near = crop_near(mesh, gt_pos, max(GT_MARGIN, 0.1 * _extent(gt_pos)))
        near.transform(to_run)
        what = "seen green / unseen red by evaluate" if source == out.coverage_mesh else "uncoloured"
        layers.append(mesh_layer("gt_surface", "Ground-truth surface", near, budget.gt_surface,
                                 f"{Path(source).name}, {what}", visible=False))
    return layers


def component_layers(out: RunOutputs, summary: dict, budget: ViewBudget, beside: float, gap: float) -> list[Layer]:
    """The components' meshes (one layer) and paths (another), shifted along +x from ``beside``."""
    comps = [c for c in summary.get("components", []) if not c.get("main") and c.get("files")]
    meshes, paths, x = o3d.geometry.TriangleMesh(), [], beside + gap
    for c in comps:
        files = {Path(f).name: out.root / f for f in c["files"]}
        mesh = _mesh(files.get("mesh.ply", Path("-")))
        pos = read_tum(files["trajectory.txt"])[1][:, :3, 3] if "trajectory.txt" in files else np.zeros((0, 3))
        pts = np.concatenate([pos, np.asarray(mesh.vertices)]) if mesh is not None else pos
        if len(pts) == 0:
            continue
        shift = np.array([x - pts[:, 0].min(), 0.0, 0.0])
        if mesh is not None:
            meshes += mesh.translate(shift)
        paths.append(pos + shift)
        x += np.ptp(pts[:, 0]) + gap
    layers = []
    if len(meshes.triangles):
        layers.append(mesh_layer("components", f"Other components ({len(comps)})", meshes,
                                 budget.components, "components/NN/mesh.ply"))
    if any(len(p) >= 2 for p in paths):
        layers.append(Layer("components_path", "Other components' paths", "segments", polyline_segments(paths),
                            colour=COMPONENT_COLOUR, note="components/NN/trajectory.txt, each in its own frame"))
    return layers


def run_layers(run: str | Path, budget: ViewBudget, gt: str | Path | None = None) -> list[Layer]:
    """Every layer of the run folder ``run`` (see the module docstring)."""
    out = RunOutputs(run)
    summary = _read_json(out.summary)
    layers = map_layers(out, budget, summary)
    seq = gt_sequence(out, gt)
    if seq is not None and out.trajectory.is_file():
        layers += gt_layers(out, seq, budget, summary)
    pts = np.concatenate([lay.positions for lay in layers]) if layers else np.zeros((0, 3))
    if len(pts):
        layers += component_layers(out, summary, budget, float(pts[:, 0].max()), 0.1 * _extent(pts))
    return layers
