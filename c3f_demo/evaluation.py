"""The demo's ``evaluate`` stage: ``c3f_slam evaluate`` of every SLAM configuration, the seven
depth metrics of the exported DepthNet on the held-out sequence, and one frame pair's matches
(SIFT vs ContraFeat) scored against the ground truth. Torch-free (onnxruntime), metres."""

from __future__ import annotations

import json

import cv2
import numpy as np

from c3f_core.atomic import atomic_write
from c3f_demo.context import DemoContext, StageFailed, slam_runs
from c3f_demo.stages import Stage
from c3f_slam.config import FrontendConfig
from c3f_slam.evaluation.depth import METRIC_NAMES, depth_metrics
from c3f_slam.io import Sequence
from c3f_slam.io.run_outputs import write_json
from c3f_slam.matching.ground_truth import PIXEL_RADIUS, ground_truth_matches
from c3f_slam.matching.match_accuracy import match_and_evaluate, near_misses
from c3f_slam.matching.visual import draw_matches
from c3f_slam.models import DepthModel, DescriptorModel
from c3f_slam.pipeline.frontend import ContraFeatDescriptors, Frontend, SiftDescriptors


def slam_results(ctx: DemoContext, run_notes: dict) -> dict:
    """``c3f_slam evaluate`` of every SLAM configuration that ran (2 at a time), then
    :func:`slam_result` of each; ``run_notes``: the slam stage's ``runs``."""
    notes = {name: dict(run_notes.get(name, {"status": "failed", "error": "not run"})) for name in ctx.slam_runs}
    errors = ctx.run_many("evaluate", {
        name: ["-m", "c3f_slam", "evaluate", str(ctx.slam_dir(name)), "--gt", str(ctx.test_seq)]
        for name, res in notes.items() if res.get("status") == "ok"})
    return {name: slam_result(ctx, name, res, errors.get(name)) for name, res in notes.items()}


def slam_result(ctx: DemoContext, name: str, res: dict, error: StageFailed | None = None) -> dict:
    """One configuration's numbers from its ``evaluation.json``; a failed run or evaluation
    (``error``), or an ATE not below the path length, is returned as failed."""
    if res.get("status") != "ok":
        return res
    if error is not None:
        return {**res, "status": "failed", "error": f"evaluate: {error}"}
    ev = json.loads((ctx.slam_dir(name) / "evaluation.json").read_text())
    if "error" in ev:
        return {**res, "status": "failed", "error": ev["error"], "registered_share": ev.get("registered_share")}
    ate = ev["ate_sim3"]["rmse_m"]
    res = {**res, "registered_share": ev["registered_share"], "ate_sim3_m": ate, "ate_se3_m": ev["ate_se3"]["rmse_m"],
           "gt_length_m": ev["gt_length_m"], "n_associated": ev.get("n_associated"), "coverage": ev.get("coverage")}
    if not np.isfinite(ate) or ate >= ev["gt_length_m"]:
        res.update(status="failed", error=f"ATE {100 * ate:.2f} cm is not below the path length "
                                          f"{100 * ev['gt_length_m']:.2f} cm: the trajectory is not usable")
    return res


def depth_evaluation(ctx: DemoContext, folder: str = "depthnet") -> dict:
    """The seven metrics (per-image median scaling, the project's protocol) and the metric error
    without scaling, of the DepthNet exported to ``models/FOLDER`` on every
    ``depth_eval_stride``-th held-out frame (metric: depth x the export's metric scale)."""
    seq = Sequence(ctx.test_seq)
    model = DepthModel(ctx.models / folder / "depthnet.onnx", threads=2)
    lo, hi = model.depth_range or (1e-3, 0.3)
    idx = list(range(0, len(seq), ctx.cfg.report.depth_eval_stride))
    pred = np.stack([model.predict(seq.read_rgb(i), seq.camera) for i in idx])
    gt = np.stack([seq.read_depth(i) for i in idx])
    scaled = depth_metrics(pred, gt, median_scaling=True, min_depth=lo, max_depth=hi)
    metric = depth_metrics(pred, gt, median_scaling=False, min_depth=lo, max_depth=hi)
    return {"frames": idx, "median_scaled": scaled, "metric": {k: metric[k] for k in METRIC_NAMES},
            "depth_range_m": [lo, hi], "metric_scale_in_model": model.metric_scale}


def depth_evaluations(ctx: DemoContext) -> dict:
    """:func:`depth_evaluation` of the network SLAM used; with test-time training on, also of the
    pre-trained one (``before_ttt``), on the same frames."""
    out = depth_evaluation(ctx)
    if (ctx.models / "depthnet_pretrained" / "depthnet.onnx").is_file():
        out["before_ttt"] = depth_evaluation(ctx, "depthnet_pretrained")
    return out


def match_evaluation(ctx: DemoContext) -> dict:
    """SIFT and ContraFeat matches of the pair (i, i + gap): the runtime's keypoints, mutual nearest
    neighbours with the runtime's ratio test, scored against ground-truth matches; draws both."""
    seq = Sequence(ctx.test_seq)
    r = ctx.cfg.report
    i = min(r.pair_frame, len(seq) - 1 - r.pair_gap)
    j = i + r.pair_gap
    rgb = [seq.read_rgb(i), seq.read_rgb(j)]
    depth = [seq.read_depth(i), seq.read_depth(j)]
    K, fcfg = seq.camera.K, FrontendConfig()
    kps = [Frontend(K, SiftDescriptors(), fcfg).keypoints(im) for im in rgb]
    gt, proj = ground_truth_matches(kps[0].xy, kps[1].xy, depth[0], depth[1], K=K, T_wi=seq.pose(i), T_wj=seq.pose(j),
                                    pixel_radius=PIXEL_RADIUS, return_projection=True)
    feat = ContraFeatDescriptors(DescriptorModel(ctx.models / "contrafeat" / "contrafeat.onnx", threads=2),
                                 seq.camera)
    out, rows = {"pair": [i, j], "keypoints": [len(kps[0]), len(kps[1])], "ground_truth": len(gt)}, []
    for name, provider in (("sift", SiftDescriptors()), ("contrafeat", feat)):
        desc = [provider.describe(im, kp) for im, kp in zip(rgb, kps)]
        ev = match_and_evaluate(desc[0], desc[1], kps[0].xy, kps[1].xy, depth_i=depth[0], depth_j=depth[1], K=K,
                                gt_matches=gt, projection=proj,
                                metric=provider.metric, ratio=fcfg.ratio, pixel_radius=PIXEL_RADIUS)
        near, _ = near_misses(ev.matches, kps[1].xy, proj, ev.correct, pixel_radius=PIXEL_RADIUS)
        rows.append(draw_matches(rgb[0], rgb[1], kps[0].xy, kps[1].xy, ev.matches, correct=ev.correct, scale=2,
                                 near=near))
        c = ev.counts
        out[name] = {"found": c.found, "correct": c.correct, "precision": c.precision, "recall": c.recall,
                     "near_misses": c.near_misses}
    path = ctx.root / "figures" / "matches.png"
    with atomic_write(path) as tmp:
        cv2.imwrite(str(tmp), cv2.cvtColor(np.concatenate(rows, axis=0), cv2.COLOR_RGB2BGR))
    out["figure"] = str(path.relative_to(ctx.root))
    return out


class Evaluate(Stage):
    """Metrics of every configuration, of the depth and of the matches (``DIR/metrics/*.json``)."""

    name = "evaluate"
    upstream = ("slam",)

    def settings(self, cfg):
        r = cfg.report
        return {"depth_eval_stride": r.depth_eval_stride, "pair": [r.pair_frame, r.pair_gap]}

    def outputs(self, ctx):
        return [ctx.root / "metrics", ctx.root / "figures" / "matches.png",
                *(ctx.log(f"{self.name}_{n}") for n in ctx.slam_runs)]

    def estimate_s(self, cfg):
        return len(slam_runs(cfg)) * 4.5 + 0.05 * cfg.simulate.test_frames + 5.0  # evaluate: 2 at a time

    def run(self, ctx, done=None):
        runs = (done or {}).get("notes", {}).get("slam", {}).get("runs", {})
        slam = slam_results(ctx, runs)
        metrics = {"slam": slam, "depth": depth_evaluations(ctx), "matches": match_evaluation(ctx)}
        for key, value in metrics.items():
            write_json(ctx.root / "metrics" / f"{key}.json", value)
        return {"failed": [n for n, r in slam.items() if r["status"] != "ok"]}
