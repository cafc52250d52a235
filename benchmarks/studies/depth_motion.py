"""Does a DepthNet export see the camera move? Predicted vs true depth change between frames
(outside CI).

SLAM with predicted depth registers frames by Kabsch on 3D points from the predicted depth,
so the translation it recovers along the viewing direction comes from how the predicted depth
of a surface point changes between two frames. This script measures that directly, without
descriptor matching: for pairs of frames (t, t + gap) of a sequence with ground-truth depth and
poses, pixels of frame t are carried into frame t + gap with the true depth and pose (visible
there: the true depth agrees within 5 %), and for each such surface point it compares

- the true change of its depth, d_true = log(z_{t+gap} / z_t), with the predicted one,
  d_pred = log(P_{t+gap}(u') / P_t(u)) (P: the network's depth at the pixel);
  ``slope``: least-squares slope of d_pred on d_true over all points of the gap (1: the
  prediction follows the motion; 0: it ignores it), ``corr`` their correlation;
- the Kabsch fit of the predicted 3D points (all carried pixels, i.e. perfect matches):
  ``|t| ratio`` = |t_est| / |t_true| (median over pairs) and ``cos`` between t_est and t_true
  (median); the same fit on the true depth is the control (ratio 1, cos 1);
- the per-frame scale of the prediction, s_t = median(P_t) / median(z_t) (the inverse of
  :func:`c3f_slam.evaluation.depth.median_scale`, the exporter's metric scale): its spread over the
  sequence (CV) and its median change between the frames of a pair, |log(s_{t+gap} / s_t)|,
  next to the true median |d_true|. A scale that jumps by more than the true depth change
  swamps the motion.

    python -m benchmarks.studies.depth_motion SEQ --depth-model runs/exported/full_warm800/depthnet.onnx \
        [--depth-model OTHER.onnx ...] --gaps 1 10 30 --pairs 60 --report /tmp/depth_motion.md

Findings so far: docs/lab_notes/2026-11-22-depth-motion.md.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from pathlib import Path

import numpy as np

from benchmarks.common import STUDIES
from benchmarks.common.report import Report
from c3f_slam.evaluation.depth import median_scale
from c3f_slam.geometry import backproject_pixels, relative_pose
from c3f_slam.io import Sequence
from c3f_slam.matching.ground_truth import project_keypoints
from c3f_slam.matching.kabsch import kabsch
from c3f_slam.matching.points import sample_depth
from c3f_slam.models import DepthModel

STRIDE = 4  # pixel grid of frame t
VISIBLE_TOL = 0.05  # true depth agreement in frame t + gap (relative)


def carry(z_t: np.ndarray, z_s: np.ndarray, K: np.ndarray, T_wt: np.ndarray, T_ws: np.ndarray):
    """Pixels of a ``STRIDE`` grid of frame t (true depth ``z_t``) carried into frame s with the
    true poses (:func:`c3f_slam.matching.ground_truth.project_keypoints`): (pixels (u, v) in t,
    sub-pixel (u, v) in s, true z in s) of those visible in s (frame s's true depth there
    agrees within ``VISIBLE_TOL``)."""
    H, W = z_t.shape
    rows, cols = np.mgrid[0:H:STRIDE, 0:W:STRIDE]
    uv_t = np.stack([cols.ravel(), rows.ravel()], 1).astype(np.float64)
    proj = project_keypoints(uv_t, z_t, z_s, K, T_wi=T_wt, T_wj=T_ws, depth_tolerance=VISIBLE_TOL)
    v = proj.visible
    return uv_t[v], proj.uv[v], proj.depth[v]


def analyse(seq: Sequence, predict: Callable[[int], np.ndarray], starts: list[int], gaps: list[int]) -> dict:
    """The measures of the module docstring for pairs (t, t + gap), t in ``starts``;
    ``predict(i)``: the predicted depth (H, W) of frame i (metres, or the network's units)."""
    K = seq.camera.K
    cache: dict[int, tuple[np.ndarray, np.ndarray]] = {}

    def frame(i: int) -> tuple[np.ndarray, np.ndarray]:
        if i not in cache:
            cache[i] = (seq.read_depth(i).astype(np.float64), np.asarray(predict(i), np.float64))
        return cache[i]

    def scale(i: int) -> float:
        """Predicted per true depth of frame i (the inverse of the metric scale)."""
        z, p = frame(i)
        return 1.0 / median_scale(p, z)

    out: dict = {}
    for gap in gaps:
        d_true, d_pred, ratio, cos, ratio_gt, cos_gt, ds, t_mm = [], [], [], [], [], [], [], []
        for t in starts:
            s = t + gap
            if s >= len(seq):
                continue
            (z_t, p_t), (z_s, p_s) = frame(t), frame(s)
            T_st = relative_pose(seq.poses[s], seq.poses[t])  # s <- t
            uv_t, uv_s, zs = carry(z_t, z_s, K, seq.poses[t], seq.poses[s])
            r0, c0 = uv_t[:, 1].astype(int), uv_t[:, 0].astype(int)
            pt, ps = p_t[r0, c0], sample_depth(p_s, uv_s)
            ok = (pt > 0) & (ps > 0)
            uv_t, uv_s, zs, pt, ps, r0, c0 = uv_t[ok], uv_s[ok], zs[ok], pt[ok], ps[ok], r0[ok], c0[ok]
            if len(zs) < 20:
                continue
            zt = z_t[r0, c0]
            d_true.append(np.log(zs / zt))
            d_pred.append(np.log(ps / pt))
            t_true = T_st[:3, 3]
            t_mm.append(1000 * np.linalg.norm(t_true))
            for dt, dsj, r_list, c_list in ((pt, ps, ratio, cos), (zt, zs, ratio_gt, cos_gt)):
                T = kabsch(backproject_pixels(uv_t, dt, K), backproject_pixels(uv_s, dsj, K))
                te = T[:3, 3]
                r_list.append(np.linalg.norm(te) / max(np.linalg.norm(t_true), 1e-12))
                c_list.append(float(te @ t_true) / max(np.linalg.norm(te) * np.linalg.norm(t_true), 1e-12))
            ds.append(abs(np.log(scale(s) / scale(t))))
        if not d_true:
            continue
        a, b = np.concatenate(d_true), np.concatenate(d_pred)
        out[gap] = {
            "pairs": len(ds), "points": len(a), "t_mm": float(np.median(t_mm)),
            "med_abs_true": float(np.median(np.abs(np.array([np.median(x) for x in d_true])))),
            "slope": float((a - a.mean()) @ (b - b.mean()) / max(((a - a.mean()) ** 2).sum(), 1e-18)),
            "corr": float(np.corrcoef(a, b)[0, 1]),
            "ratio": float(np.median(ratio)), "cos": float(np.median(cos)),
            "ratio_gt": float(np.median(ratio_gt)), "cos_gt": float(np.median(cos_gt)),
            "scale_jump": float(np.median(ds)),
        }
    scales = np.array([scale(i) for i in sorted(cache)])
    return {"gaps": out, "scale_cv": float(scales.std() / scales.mean()), "scale_median": float(np.median(scales)),
                "frames": len(cache)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("sequence", type=Path, help="sequence folder with depth/ and poses.txt")
    ap.add_argument("--depth-model", type=Path, action="append", required=True,
                    help="DepthNet ONNX export (repeatable: each gets its own rows)")
    ap.add_argument("--gaps", type=int, nargs="+", default=[1, 10, 30])
    ap.add_argument("--pairs", type=int, default=60, help="start frames, evenly spaced over the sequence")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--report", type=Path, default=STUDIES / "depth_motion.md")
    args = ap.parse_args()
    seq = Sequence(args.sequence)
    if not (seq.has_depth and seq.has_poses):
        raise SystemExit(f"{args.sequence}: needs depth/ and poses.txt")
    if min(args.gaps) < 1 or args.pairs < 1:
        raise SystemExit("--gaps must be >= 1 and --pairs >= 1")
    starts = np.linspace(0, len(seq) - 1 - max(args.gaps), args.pairs).round().astype(int).tolist()
    rows = []
    for path in args.depth_model:
        model = DepthModel(path, args.threads, "--depth-model")
        res = analyse(seq, lambda i: model.predict(seq.read_rgb(i), seq.camera), starts, args.gaps)  # noqa: B023
        print(path, res, flush=True)
        for gap, r in res["gaps"].items():
            rows.append(
                f"| {path.parent.name}/{path.name} | {gap} | {r['pairs']} ({r['points']}) | {r['t_mm']:.2f} | "
                f"{100 * r['med_abs_true']:.2f} | {r['slope']:.3f} | {r['corr']:.3f} | "
                f"{r['ratio']:.2f} | {r['cos']:.2f} | "
                f"{r['ratio_gt']:.2f} / {r['cos_gt']:.2f} | {100 * r['scale_jump']:.2f} | "
                f"{res['scale_median']:.2f} / {res['scale_cv']:.3f} |")
    report = Report(__file__, "Does the depth network see the camera move?")
    text = report.render([
        (f"- Sequence: {args.sequence} ({len(seq)} frames, {seq.camera.width}x{seq.camera.height} px); "
         f"{args.pairs} start frames evenly spaced; pixels on a {STRIDE}-px grid of frame t carried into frame t + gap "
         f"with the true depth and pose, kept where the true depth there agrees within {100 * VISIBLE_TOL:.0f} %."),
        ("- Columns: pairs (points); median true camera translation of a pair (mm); median over pairs of "
         "|median true log depth change| (%); slope and correlation of the predicted on the true log depth "
         "change of the same surface points (1 and 1: the prediction follows the motion; slope 0: it ignores it); "
         "Kabsch on the predicted 3D points of all carried pixels (perfect matches): median |t_est| / |t_true| and "
         "median cosine between t_est and t_true; the same Kabsch on the true depth (control); median change of "
         "the prediction's per-frame scale median(P) / median(z) between the two frames, |log(s_{t+gap}/s_t)| (%); "
         "that scale's median and spread (CV) over all frames read."), "",
        ("| depth model | gap | pairs (points) | true translation mm | true depth change % | slope | corr | "
         "translation ratio | cos | "
         "GT-depth control ratio / cos | scale change % | scale median / CV |"),
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
        *rows])
    report.write(args.report, text)
    print(text)


if __name__ == "__main__":
    main()
