"""The truth of a run's unseen-surface estimate (``evaluate --gt``).

The same quantities as the run's coverage.json, computed from the ground truth: the wall is
modelled on the sequence's true mesh, seen from the true camera poses of every frame the
run streamed (registered or not), occluded by the true surface (folds included) — the same
visibility the true depth maps give — with the run's coverage settings, image size and
intrinsics. Segments are the same ``segment`` metres from the first camera position, each
along its own centreline (the estimated and the true camera paths), paired by index.
``truth_registered`` is the truth seen from the frames the run registered only: the
difference to ``truth`` is what tracking losses cost the estimate, the rest is the estimator's.
``dataset`` (where the sequence has ``mesh_observed.txt``, e.g. converted C3VD) is the data
set's own unseen share: the area of the faces it flags never observed, on the true
centreline's wall and segments (:mod:`c3f_slam.coverage.dataset_truth`).
Shares 0..1 in the JSON; the report prints percentages.
"""

from __future__ import annotations

import json

import numpy as np
import open3d as o3d

from c3f_slam.coverage import CoverageMap, CoverageUnavailable, compute_coverage, settings_from_dict
from c3f_slam.coverage.dataset_truth import FLAGS_FILE, dataset_unseen, read_observed_flags
from c3f_slam.coverage.render import draw_coverage_map
from c3f_slam.evaluation.trajectory import associate
from c3f_slam.frames.tissue import read_mask_png
from c3f_slam.io import Sequence, read_tum
from c3f_slam.io.run_outputs import RunOutputs

TRUTH_MAP = "coverage_map_truth.png"


def run_frame_poses(seq: Sequence, summary: dict) -> np.ndarray:
    """True camera-to-world poses of the frames the run streamed (its stride and frame count)."""
    stride = int(summary.get("stride") or 1)
    n = summary.get("frames")
    poses = seq.poses[::stride]
    return poses if n is None else poses[: int(n)]


def registered_true_poses(outputs: RunOutputs, seq: Sequence) -> np.ndarray:
    """True poses of the frames the run registered (trajectory.txt's timestamps)."""
    stamps, _ = read_tum(outputs.trajectory)
    _, ig = associate(stamps, seq.timestamps)
    return seq.poses[ig]


def _shares(cov: CoverageMap, segment: float) -> tuple[float, list[float]]:
    return cov.unseen_share(), [s["unseen_share"] for s in cov.segments(segment)]


def unseen_truth(outputs: RunOutputs, seq: Sequence, summary: dict) -> dict:
    """``{estimate, truth, error_pp, segments: [{start_m, end_m, estimate, truth, error_pp}], ...}``
    for the run in ``outputs``; ``{"status": reason}`` when either side is missing."""
    est = json.loads(outputs.coverage_json.read_text())
    if est.get("status") != "ok":
        return {"status": f"no estimate ({est.get('reason', est.get('status'))})"}
    if not {"K", "image_size", "depth_min", "depth_max"} <= set(est.get("settings", {})):
        return {"status": f"no estimate settings in {outputs.coverage_json.name} (an older run?)"}
    if seq.mesh_path is None:
        return {"status": f"no ground truth ({seq.root} has no mesh.ply)"}
    mask = None
    if "tissue_mask_share" in est["settings"]:  # the run's tissue area on the grid coverage tested
        w, h = est["settings"]["image_size"]
        mask = read_mask_png(outputs.coverage_mask, int(w), int(h), "coverage mask")
    cfg, view, K = settings_from_dict(est["settings"], mask)
    mesh = o3d.io.read_triangle_mesh(str(seq.mesh_path))
    try:
        truth = compute_coverage(mesh, run_frame_poses(seq, summary), K, view, cfg)
        reg, reg_segs = _shares(compute_coverage(mesh, registered_true_poses(outputs, seq), K, view, cfg),
                                cfg.segment)
    except CoverageUnavailable as exc:
        return {"status": f"no ground truth ({exc})"}
    draw_coverage_map(outputs.root / TRUTH_MAP, truth, cfg.segment,
                      title=f"ground truth: unseen {100 * truth.unseen_share():.1f} % of the wall")
    flags = seq.root / FLAGS_FILE
    ds = (dataset_unseen(mesh, read_observed_flags(flags, len(mesh.triangles)), truth.wall.centreline, cfg.segment,
                         cfg.max_radius) if flags.is_file() else None)
    ds_segs = [s["unseen_share"] for s in ds["segments"]] if ds else []
    segs = []
    for k, (e, t, r) in enumerate(zip(est["segments"], truth.segments(cfg.segment), reg_segs, strict=False)):
        segs.append({"start_m": e["start_m"], "end_m": e["end_m"], "truth_end_m": t["end_m"],
                     "estimate": e["unseen_share"], "truth": t["unseen_share"], "truth_registered": r,
                     "error_pp": 100 * (e["unseen_share"] - t["unseen_share"]),
                     **({"dataset": ds_segs[k]} if k < len(ds_segs) else {})})
    u = truth.unseen_share()
    extra = {"dataset": ds["unseen_share"], "dataset_file": FLAGS_FILE} if ds else {}
    return {"status": "ok", **extra, "estimate": est["unseen_share"], "truth": u, "truth_registered": reg,
            "error_pp": 100 * (est["unseen_share"] - u),
            "explored_length_m": {"estimate": est["explored_length_m"], "truth": truth.length},
            "segment_m": cfg.segment, "segments": segs, "truth_frames_used": truth.frames_used,
            "truth_map": TRUTH_MAP}


def format_unseen(u: dict) -> list[str]:
    """Report lines: overall and per segment, estimate vs truth, in percent / cm."""
    if u.get("status") != "ok":
        return [f"unseen wall: {u.get('status')}"]
    L = u["explored_length_m"]
    lines = [f"unseen wall: estimate {100 * u['estimate']:.1f} %, truth {100 * u['truth']:.1f} % "
             f"({u['error_pp']:+.1f} pp; explored {100 * L['estimate']:.1f} cm, truth {100 * L['truth']:.1f} cm)",
             f"  (truth from the registered frames only: {100 * u['truth_registered']:.1f} %)"]
    ds = "dataset" in u
    if ds:
        lines.append(f"  (the data set's own flags, {u['dataset_file']}: {100 * u['dataset']:.1f} % never observed)")
    lines.append(f"  {'segment [cm]':>14} {'estimate %':>10} {'truth %':>8} {'diff pp':>8} {'truth reg. %':>12}"
                 + (f" {'data set %':>10}" if ds else ""))
    for s in u["segments"]:
        lines.append(f"  {100 * s['start_m']:6.1f}-{100 * s['end_m']:<6.1f} {100 * s['estimate']:10.1f} "
                     f"{100 * s['truth']:8.1f} {s['error_pp']:+8.1f} {100 * s['truth_registered']:12.1f}"
                     + (f" {100 * s.get('dataset', float('nan')):10.1f}" if ds else ""))
    return lines
