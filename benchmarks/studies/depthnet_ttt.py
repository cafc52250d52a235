"""Test-time training (configs/depthnet/ttt.yaml) on a held-out simulator sequence: depth error
and SLAM on predicted depth, before and after, side by side in one run (outside CI).

A DepthNet trained on other sequences (``--base-config`` = its run's ``config.yaml``,
``--base-ckpt``) is fine-tuned self-supervised on every frame of ``--sequence`` (no ground
truth used in training), then both networks are

1. tested on that sequence with the project's metric function (the seven metrics, per-image
   median scaling; Sq Rel and RMSE in cm, as the paper prints them);
2. exported with the base run's config, so the metric depth scale the runtime applies is
   measured on the base run's training sequences, never on the test sequence;
3. run through ``c3f_slam`` on the sequence with their predicted depth (SIFT descriptors) and
   evaluated against its ground truth (ATE after Sim(3), registered share).

The paper's schedule is 200 epochs, lr halved at 80/120/170; ``--epochs E`` shortens it for a
CPU and scales the milestones with it (the report says which were used).

    python -m benchmarks.studies.depthnet_ttt --base-config runs/full/tb/version_0/config.yaml \\
        --base-ckpt runs/full/tb/version_0/checkpoints/last.ckpt --sequence data/test0 --epochs 10 \\
        --work /tmp/ttt --out /tmp/depthnet_ttt.md

Findings so far: docs/lab_notes/2026-12-01-depthnet-ttt.md.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from benchmarks.common import ROOT, STUDIES
from benchmarks.common.depth_metrics import HEADER, logged_test_metrics, metric_cells
from benchmarks.common.report import Report

PAPER_EPOCHS, PAPER_MILESTONES = 200, (80, 120, 170)


def scaled_milestones(epochs: int) -> list[int]:
    """The paper's milestones at the same fractions of a shorter schedule (distinct, >= 1)."""
    out: list[int] = []
    for m in PAPER_MILESTONES:
        k = max(1, round(m * epochs / PAPER_EPOCHS))
        out.append(max(k, out[-1] + 1) if out else k)
    return out


def test_metrics(base_config: Path, ckpt: Path, sequence: Path, size: list[int], root: Path) -> dict:
    from c3f_models.cli import main

    cli = main(["test", "--config", str(base_config), "--ckpt_path", str(ckpt), "--data.data_dir", str(sequence),
                "--data.split.train", "[]", "--data.split.val", "[]", "--data.split.test", json.dumps([sequence.name]),
                "--data.frames.size", json.dumps(size), "--trainer.limit_test_batches", "1.0",
                "--trainer.logger", "false",
                "--trainer.default_root_dir", str(root), "--trainer.enable_progress_bar", "false"])
    return logged_test_metrics(cli.trainer.callback_metrics)


def tune(base_config: Path, ckpt: Path, sequence: Path, *, epochs: int, root: Path, seed: int,
         overrides: list[str]) -> tuple[Path, float]:
    from c3f_models.cli import main

    t0 = time.perf_counter()
    extra = [a for kv in overrides for a in (f"--model.{kv.partition('=')[0]}", kv.partition("=")[2])]
    cli = main(["fit", "--config", str(base_config), "--config", str(ROOT / "configs/depthnet/ttt.yaml"), *extra,
                "--model.init_weights", str(ckpt), "--data.data_dir", str(sequence),
                "--trainer.max_epochs", str(epochs), "--model.optim.milestones", json.dumps(scaled_milestones(epochs)),
                "--trainer.default_root_dir", str(root), "--trainer.logger.init_args.save_dir", str(root),
                "--trainer.enable_progress_bar", "false", "--seed_everything", str(seed)])
    return Path(cli.trainer.checkpoint_callback.last_model_path), time.perf_counter() - t0


def export(base_config: Path, ckpt: Path, out: Path) -> Path:
    from c3f_models.cli import main

    main(["export", "--config", str(base_config), "--ckpt_path", str(ckpt), "--output_dir", str(out),
          "--trainer.logger", "false"])
    return out / "depthnet.onnx"


def slam(sequence: Path, depth_model: Path, out: Path, min_corr: int) -> dict:
    from c3f_slam.config import preset as slam_preset
    from c3f_slam.evaluation.trajectory import evaluate_trajectory
    from c3f_slam.io import Sequence, read_tum
    from c3f_slam.pipeline import RunInputs, run_slam

    cfg = slam_preset("colon", fragments={"min_correspondences": min_corr}, fusion={"enabled": False})
    try:
        inputs = RunInputs(descriptors="sift", depth_source="model", depth_model=str(depth_model))
        s = run_slam(sequence, out, cfg, inputs, progress=False, overwrite=True)  # the benchmark owns its work folder
    except Exception as exc:  # noqa: BLE001 -- a failed run is a result: report it
        return {"error": str(exc)}
    st, P = read_tum(out / "trajectory.txt")
    g = Sequence(sequence)
    return {"summary": s, "eval": evaluate_trajectory(st, P, g.timestamps, g.poses, n_frames=s["frames"]), "out": out}


def common_ate(sequence: Path, runs: dict) -> tuple[dict, int]:
    """ATE Sim(3) RMSE (m) of each run over the frames both registered, and their number."""
    from c3f_slam.evaluation.trajectory import common_frames_ate
    from c3f_slam.io import Sequence, read_tum

    if any("error" in r for r in runs.values()):
        return {}, 0
    g = Sequence(sequence)
    return common_frames_ate({k: read_tum(r["out"] / "trajectory.txt") for k, r in runs.items()}, g.timestamps,
                             g.poses)


def _row(name: str, m: dict) -> str:
    return f"| {name} | {metric_cells(m)} | {m['depth_cv']:.3f} |"


def _slam_row(name: str, r: dict, common: float | None) -> str:
    if "error" in r:
        return f"| {name} | failed: {r['error']} | | | | |"
    ev, s = r["eval"], r["summary"]
    scale = f"{s['depth_scale']['factor']:.3f} ({s['depth_scale']['source']})"
    shared = f"{100 * common:.2f}" if common is not None else "-"
    if "ate_sim3" not in ev:
        return f"| {name} | {ev.get('error', 'no ATE')} | {100 * ev['registered_share']:.1f} | | {shared} | {scale} |"
    ate = ev["ate_sim3"]
    return (f"| {name} | {100 * ate['rmse_m']:.2f} / {100 * ate['std_m']:.2f} | {100 * ev['registered_share']:.1f} | "
            f"{100 * ev['gt_length_m']:.1f} | {shared} | {scale} |")


def parse_args() -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--base-config", type=Path, required=True, help="config.yaml of the run that made --base-ckpt")
    ap.add_argument("--base-ckpt", type=Path, required=True)
    ap.add_argument("--sequence", type=Path, required=True, help="held-out sequence (project layout, true depth)")
    ap.add_argument("--epochs", type=int, default=10)
    ap.add_argument("--size", type=int, default=128, help="network input size of the base run")
    ap.add_argument("--min-correspondences", type=int, default=15, help="SLAM new-fragment threshold (128 px: 15)")
    ap.add_argument("--model", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                    help="model argument of the test-time training only (repeatable), "
                         "e.g. loss.use_depth_consistency=false")
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--work", type=Path, default=Path("/tmp/depthnet_ttt"))
    ap.add_argument("--out", type=Path, default=STUDIES / "depthnet_ttt.md")
    a = ap.parse_args()
    bad = [kv for kv in a.overrides if "=" not in kv or not kv.partition("=")[0]]
    if bad:
        ap.error(f"--model: expected KEY=VALUE, got {bad[0]!r}")
    for p in (a.base_config, a.base_ckpt):
        if not p.is_file():
            ap.error(f"{p}: file not found")
    if not (a.sequence / "depth").is_dir():
        ap.error(f"--sequence {a.sequence}: needs true depth (a depth/ folder) to measure the error")
    return a


def report_body(a: argparse.Namespace, before: dict, after: dict, fit_s: float,
                runs: dict) -> tuple[list[str], dict]:
    """Set-up bullets, the depth metrics before / after and the SLAM table (lengths in cm); also
    the ATE (m) of each run on the frames both registered."""
    from c3f_slam.evaluation.trajectory import frame_motion
    from c3f_slam.io import Sequence

    shared, n_shared = common_ate(a.sequence, runs)
    seq = Sequence(a.sequence)
    motion = frame_motion(seq.poses)
    ms = scaled_milestones(a.epochs)
    ratio = {k: after[k] / before[k] for k in ("abs_rel", "sq_rel", "rmse", "rmse_log")}
    return [
        (f"- Base network: `{a.base_ckpt}` (config `{a.base_config}`); held-out sequence `{a.sequence}` "
         f"({len(seq)} frames, {seq.camera.width}x{seq.camera.height}; true motion per frame: median "
         f"{1e3 * motion.trans.median:.2f} mm, {motion.rot_deg.median:.2f} deg), never seen by the base run."),
        f"- Test-time training: `configs/depthnet/ttt.yaml` from the base weights (optimiser not resumed), "
        f"self-supervised on all {len(seq)} frames, {a.epochs} epochs with the lr halved at epochs {ms} "
        f"(the paper: {PAPER_EPOCHS} epochs, {list(PAPER_MILESTONES)}), {fit_s / 60:.1f} min on the CPU "
        f"({a.threads} torch thread), seed {a.seed}"
        + (f", model overrides for the tuning: {', '.join(a.overrides)}." if a.overrides else "."),
        ("- Depth metrics on the same sequence, per-image median scaling; Sq Rel and RMSE in cm. The sequence's "
         "true depth is used only here and by the SLAM evaluation, never in training or in the depth scale."),
        "",
        f"| network | {HEADER} | depth CV |",
        "|---|---|---|---|---|---|---|---|---|",
        _row("base (before TTT)", before),
        _row(f"after TTT ({a.epochs} epochs)", after),
        "",
        "After / before: " + ", ".join(f"{k} {v:.3f}" for k, v in ratio.items()) + ".",
        "",
        ("SLAM on the sequence with each network's predicted depth (SIFT, `--set "
         f"fragments.min_correspondences={a.min_correspondences}`, both exported with the base run's config: depth "
         "scale measured on the base run's training sequences):"),
        "",
        (f"| network | ATE Sim(3) cm (RMSE / std) | registered % | GT length cm | ATE cm, the {n_shared} frames "
         "both registered | depth scale |"),
        "|---|---|---|---|---|---|",
        _slam_row("base (before TTT)", runs["base"], shared.get("base")),
        _slam_row("after TTT", runs["ttt"], shared.get("ttt")),
    ], shared


def main() -> None:
    a = parse_args()
    import torch

    torch.set_num_threads(a.threads)
    size = [a.size, a.size]
    before = test_metrics(a.base_config, a.base_ckpt, a.sequence, size, a.work / "test_base")
    tuned, fit_s = tune(a.base_config, a.base_ckpt, a.sequence, epochs=a.epochs, root=a.work / "ttt", seed=a.seed,
                        overrides=a.overrides)
    after = test_metrics(a.base_config, tuned, a.sequence, size, a.work / "test_ttt")
    runs = {}
    for name, ckpt in (("base", a.base_ckpt), ("ttt", tuned)):
        onnx = export(a.base_config, ckpt, a.work / f"export_{name}")
        runs[name] = slam(a.sequence, onnx, a.work / f"slam_{name}", a.min_correspondences)
    body, shared = report_body(a, before, after, fit_s, runs)
    report = Report(__file__, "Test-time training on a held-out sequence")
    text = report.render(body)
    report.write(a.out, text)
    (a.work / "depthnet_ttt.json").write_text(json.dumps({"before": before, "after": after, "slam": {
        k: {"eval": v.get("eval"), "error": v.get("error")} for k, v in runs.items()}, "common_ate_m": shared},
        indent=2, default=str))
    print(text)


if __name__ == "__main__":
    main()
