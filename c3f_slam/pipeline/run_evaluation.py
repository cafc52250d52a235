"""``evaluate`` of a run folder against a ground-truth sequence (docs/design.md, Evaluation).

Writes OUT/evaluation.json (lengths in metres), OUT/trajectory.png (estimate aligned with
Sim(3) vs ground truth) and, when the sequence has mesh.ply and the run a mesh.ply,
OUT/coverage.ply (ground truth painted seen / unseen after aligning the reconstruction with
the ATE's transform: Sim(3), or SE(3) in RGB-D mode). When the run wrote components beside
the main map (OUT/components/NN/, :mod:`c3f_slam.pipeline.components`), ``components`` gives
the ATE of each of them and of the main map, each aligned on its own (Sim(3)). When the run
has coverage.json, ``unseen`` gives the truth of its unseen-surface estimate
(OUT/coverage_map_truth.png: :mod:`c3f_slam.pipeline.coverage_evaluation`).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import open3d as o3d

from c3f_core.errors import InputError
from c3f_slam.evaluation.surface import coverage_mesh, surface_coverage
from c3f_slam.evaluation.trajectory import associate, ate, evaluate_trajectory
from c3f_slam.evaluation.trajectory_plot import plot_trajectories
from c3f_slam.fusion.tsdf import write_mesh
from c3f_slam.io import Sequence, read_tum
from c3f_slam.io.run_outputs import RunOutputs, write_json
from c3f_slam.pipeline.coverage_evaluation import format_unseen, unseen_truth

#: written last by :func:`evaluate_run`: its presence means the evaluation is complete
EVALUATION_NAME = "evaluation.json"


def evaluate_run(out: str | Path, gt: str | Path, coverage_samples: int = 50_000) -> dict:
    """Metrics of the run in ``out`` against the sequence ``gt``; writes the files, returns the dict."""
    outputs = RunOutputs(out)
    if not outputs.trajectory.is_file():
        raise InputError(f"{outputs.trajectory}: no trajectory (is {out} a run folder?)")
    seq = Sequence(gt)
    if not seq.has_poses:
        raise InputError(f"{seq.root}: no poses.txt to evaluate against")
    stamps, poses = read_tum(outputs.trajectory)
    summary = {}
    if outputs.summary.is_file():
        summary = json.loads(outputs.summary.read_text())
    if summary.get("status", "ok") != "ok":
        raise InputError(f"{out}: the run did not complete (summary.json status {summary.get('status')}: "
                         f"{summary.get('error', 'no error recorded')}); its outputs are partial, not evaluated")
    n_frames = summary.get("frames") or len(seq)
    res = evaluate_trajectory(stamps, poses, seq.timestamps, seq.poses, n_frames=n_frames)
    # the inputs are checked: from here the folder holds no evaluation until the new one is whole
    (Path(out) / EVALUATION_NAME).unlink(missing_ok=True)
    rgbd = summary.get("depth_source", "files") == "files"
    res["alignment_for_mesh"] = "se3" if rgbd else "sim3"
    res["gt_sequence"] = str(seq.root.resolve())  # where the view finds the true path and surface
    if "error" not in res:
        ie, ig = associate(stamps, seq.timestamps)
        a = ate(poses[ie], seq.poses[ig], "sim3")
        plot_trajectories(outputs.trajectory_png, seq.poses[:, :3, 3], a.aligned[:, :3, 3],
                          title=f"ATE (Sim3) {100 * a.stats.rmse:.2f} cm")
        res["trajectory_png"] = outputs.trajectory_png.name
        if seq.mesh_path is not None and outputs.mesh.is_file():
            al = ate(poses[ie], seq.poses[ig], res["alignment_for_mesh"])
            recon = o3d.io.read_triangle_mesh(str(outputs.mesh))
            T = np.eye(4)
            T[:3, :3], T[:3, 3] = al.scale * al.R, al.t
            recon.transform(T)
            gt_mesh = o3d.io.read_triangle_mesh(str(seq.mesh_path))
            res["coverage"] = surface_coverage(gt_mesh, recon, n_samples=coverage_samples).as_dict()
            painted = coverage_mesh(gt_mesh, recon)
            write_mesh(painted, outputs.coverage_mesh)
            res["coverage_mesh"] = outputs.coverage_mesh.name
    res["components"] = component_ates(outputs, seq, summary.get("components", []))
    if outputs.coverage_json.is_file():
        res["unseen"] = unseen_truth(outputs, seq, summary)
    write_json(Path(out) / EVALUATION_NAME, res)
    return res


def component_ates(outputs: RunOutputs, seq: Sequence, components: list[dict]) -> list[dict]:
    """Per component of summary.json's ``components`` with a trajectory file: frames, ATE
    (Sim(3), the component aligned on its own; metres) and that ATE as a share of the
    ground-truth path length over its frames."""
    out = []
    for c in components:
        traj = next((f for f in c.get("files", []) if f.endswith("trajectory.txt")), None)
        if traj is None:
            continue
        stamps, poses = read_tum(outputs.root / traj)
        ev = evaluate_trajectory(stamps, poses, seq.timestamps, seq.poses)
        row = {"id": c["id"], "main": c["main"], "trajectory": traj, "frames": len(stamps),
               "n_associated": ev["n_associated"]}
        if "error" in ev:
            row["error"] = ev["error"]
        else:
            rmse, length = ev["ate_sim3"]["rmse_m"], ev["gt_length_m"]
            row.update(ate_sim3_rmse_m=rmse, scale=ev["ate_sim3"]["scale"], gt_length_m=length,
                       ate_share_of_length=rmse / length if length > 0 else None)
        out.append(row)
    return out


def format_report(res: dict) -> str:
    """Lines for the terminal, lengths in cm."""
    lines = [(f"registered: {100 * res.get('registered_share', 0):.1f} % "
              f"({res.get('n_estimated', 0)} poses, {res.get('n_associated', 0)} with ground truth)")]
    if "error" in res:
        return "\n".join(lines + [f"error: {res['error']}"])
    for key in ("ate_sim3", "ate_se3"):
        a = res[key]
        lines.append(f"ATE {a['align']}: RMSE {100 * a['rmse_m']:.3f} cm, std {100 * a['std_m']:.3f} cm"
                     + (f" (scale {a['scale']:.4f})" if a["align"] == "sim3" else ""))
    r = res["rpe"]
    lines.append(f"RPE (delta {r['delta']}): trans RMSE {100 * r['trans_rmse_m']:.3f} cm, "
                 f"rot RMSE {r['rot_rmse_deg']:.3f} deg")
    lines.append(f"ground-truth trajectory length: {100 * res['gt_length_m']:.1f} cm")
    if "coverage" in res:
        c = res["coverage"]
        lines.append(f"coverage: {100 * c['share']:.1f} % of the ground-truth surface within "
                     f"{1000 * c['threshold']:.1f} mm")
    comps = res.get("components", [])
    if any(not c["main"] for c in comps):
        lines += _component_table(comps)
    if "unseen" in res:
        lines += format_unseen(res["unseen"])
    return "\n".join(lines)


def _component_table(comps: list[dict]) -> list[str]:
    """The per-component ATE lines of :func:`format_report` (lengths in cm)."""
    lines = ["components (ATE Sim(3), each aligned on its own; path: its ground-truth path length):",
             f"  {'id':<7} {'frames':>6} {'ATE [cm]':>9} {'% of path':>9} {'path [cm]':>9}  trajectory"]
    for c in comps:
        name = f"{c['id']}{' main' if c['main'] else ''}"
        if "error" in c:
            lines.append(f"  {name:<7} {c['frames']:>6} {'-':>9} {'-':>9} {'-':>9}  {c['trajectory']} ({c['error']})")
            continue
        share = c["ate_share_of_length"]
        pct = f"{100 * share:.2f}" if share is not None else "-"
        lines.append(f"  {name:<7} {c['frames']:>6} {100 * c['ate_sim3_rmse_m']:>9.3f} {pct:>9} "
                     f"{100 * c['gt_length_m']:>9.1f}  {c['trajectory']}")
    return lines
