"""Why test-time training from the zoo depth model hurts, and which schedule does not: TTT
variants on two held-out sequences (``seq1_s2001``: a trained appearance; ``seq5_s2005``: the
unseen one), Abs Rel before and after, and the photometric objective at the truth.

- ``variants``: 60 steps of batch 4 of the paper's objective (``configs/depthnet/ttt.yaml`` +
  ``paper_objective.yaml``, the guard on) from ``zoo:c3f-depth-r18w32`` with one change each
  (learning rate; a PoseNet-only warm-up with the depth network's batch-norm statistics frozen
  or adapting; no learning at all, which leaves only the batch-norm statistics to move).
  ``--variants`` picks some (keys of :data:`VARIANTS`).
- ``objective``: the mean photometric term L_ph (and the whole loss) of the zoo model's
  predicted depth and poses against the simulator's true depth and poses on the first 48
  triplets of each sequence: whether the objective's minimum is near the truth, and which of
  depth and pose is off.

    python -m benchmarks.studies.zoo_ttt_variants --work /tmp/ttt_variants
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from benchmarks.common import ROOT, STUDIES
from benchmarks.common.report import Report
from c3f_models.zoo.recipes import HELD_OUT
from c3f_models.zoo.train import simulate
from c3f_models.zoo.ttt import tune_and_export

MODEL = "zoo:c3f-depth-r18w32"
SEQUENCES = ("seq1_s2001", "seq5_s2005")
STEPS = 60
#: variant -> (its label in the report and results.json, options after ttt.yaml + paper_objective.yaml;
#: ttt.yaml's own pose warm-up is 30 steps)
VARIANTS = {
    "lr1e-4": ("lr 1e-4, no warm-up", ["--model.pose_warmup_steps", "0"]),
    "lr1e-5": ("lr 1e-5, no warm-up", ["--model.pose_warmup_steps", "0", "--model.optim.lr", "1e-5"]),
    "lr0": ("lr 0 (batch-norm statistics only)", ["--model.pose_warmup_steps", "0", "--model.optim.lr", "0.0"]),
    "warmup": ("lr 1e-4, PoseNet alone for 30 steps, batch-norm statistics frozen",
               ["--model.warmup_adapts_norm", "false"]),
    "warmup_lr1e-5": ("lr 1e-5, PoseNet alone for 30 steps, batch-norm statistics frozen",
                      ["--model.warmup_adapts_norm", "false", "--model.optim.lr", "1e-5"]),
    "warmup_norm": ("lr 1e-4, PoseNet alone for 30 steps while the batch-norm statistics adapt (ttt.yaml)", []),
    "norm_only": ("PoseNet alone for all 60 steps while the batch-norm statistics adapt",
                  ["--model.pose_warmup_steps", "60"]),
}


def variant(key: str, seq: Path, work: Path) -> dict:
    from c3f_models.zoo.evaluate import depth_heldout
    from c3f_slam.models import zoo
    entry = zoo.entry(MODEL, "--model")
    run = work / "runs" / key / seq.name
    checkpoints = tune_and_export(MODEL, entry.folder / "config.yaml", seq, run, STEPS, extra=tuple(VARIANTS[key][1]))
    before = depth_heldout(entry.file_for("depth", "--model"), [seq])["per_sequence"][seq.name]["median_scaled"]
    after = depth_heldout(run / "onnx" / "depthnet.onnx", [seq])["per_sequence"][seq.name]["median_scaled"]
    guard = json.loads((checkpoints / "guard.json").read_text())
    return {"before": before["abs_rel"], "after": after["abs_rel"], "guard_step": guard["best_step"],
            "guard_events": [e["event"] for e in guard["events"]]}


def objective_at_truth(seq: Path, triplets: int = 48) -> dict:
    """Mean L_ph and loss of (predicted depth, predicted poses), (true depth, true poses) and
    (predicted depth median-scaled to the truth, true poses), under the paper's objective."""
    import torch
    import yaml

    from c3f_models.depth.module import DepthNet
    from c3f_models.depth.objective import compose_triplet_poses
    from c3f_slam.models import zoo
    from datamodules.sequence import C3FSequenceDataModule

    entry = zoo.entry(MODEL, "--model")
    cfg = yaml.safe_load((entry.folder / "config.yaml").read_text())["model"]["init_args"]
    paper = yaml.safe_load((ROOT / "configs/depthnet/paper_objective.yaml").read_text())["model"]["init_args"]
    cfg = {**{k: v for k, v in cfg.items() if k != "init_weights"}, "loss": {**cfg["loss"], **paper["loss"]}}
    model = DepthNet(**cfg, init_weights=MODEL)
    model.setup("fit")
    model.eval()
    dm = C3FSequenceDataModule(data_dir=str(seq), split={"train": None, "val": None, "test": None,
                                                         "val_fraction": 0.0, "test_fraction": 0.0},
                               frames={"size": [128, 128], "specular": True}, loader={"batch_size": 8})
    dm.setup("fit")
    sums: dict[str, list[float]] = {}
    seen = 0
    inv = torch.linalg.inv
    with torch.no_grad():
        for batch in dm.train_dataloader():
            images, specular, K = model._unpack(batch)
            b = images[0].shape[0]
            disps = model.depth_net(torch.cat([images[k] for k in (1, 0, 2)]))
            pred = {k: [model.depth_net.to_depth(d[n * b:(n + 1) * b]) for d in disps] for n, k in enumerate((1, 0, 2))}
            T = model.pose_net(torch.cat([images[0], images[1]]), torch.cat([images[1], images[2]]))
            P = batch["pose"]  # (B, 3, 4, 4) camera-to-world
            true_poses = compose_triplet_poses(inv(P[:, 1]) @ P[:, 0], inv(P[:, 2]) @ P[:, 1])
            true = {k: [batch["depth"][:, k]] for k in (1, 0, 2)}
            scaled = {}
            for k in (1, 0, 2):
                p, g = pred[k][0], batch["depth"][:, k]
                ratio = g.flatten(1).median(1).values / p.flatten(1).median(1).values
                scaled[k] = [p * ratio.view(-1, 1, 1, 1)]
            cases = {"predicted depth, predicted poses": (pred, compose_triplet_poses(T[:b], T[b:])),
                     "true depth, true poses": (true, true_poses),
                     "predicted depth (median-scaled), true poses": (scaled, true_poses)}
            for name, (depths, poses) in cases.items():
                terms = model.objective(images, specular, depths, lambda d: d, poses, K)
                sums.setdefault(name, []).append(b * float(terms.ph))
                sums.setdefault(name + " (loss)", []).append(b * float(terms.loss))
            seen += b
            if seen >= triplets:
                break
    return {name: sum(v) / seen for name, v in sums.items()}


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--work", type=Path, required=True)
    ap.add_argument("--variants", nargs="+", choices=list(VARIANTS), default=list(VARIANTS))
    ap.add_argument("--report", type=Path, default=STUDIES / "zoo_ttt_variants.md")
    a = ap.parse_args(argv)
    seqs = simulate(tuple(s for s in HELD_OUT if s.name in SEQUENCES), 128, a.work / "heldout")
    results_path = a.work / "results.json"
    results = json.loads(results_path.read_text()) if results_path.is_file() else {}
    results.setdefault("objective", {})
    for seq in seqs:
        results["objective"][seq.name] = objective_at_truth(seq)
        for key in a.variants:
            results.setdefault(VARIANTS[key][0], {})[seq.name] = variant(key, seq, a.work)
            results_path.write_text(json.dumps(results, indent=2) + "\n")
    body = [f"{STEPS} steps of batch 4 from `{MODEL}`, the guard on (it ends on the healthy snapshot with "
            "the lowest photometric term, or rolls back on a collapse). Abs Rel median-scaled.", "",
            "| variant | " + " | ".join(f"{s} before -> after (change %, guard: kept step, events)" for s in SEQUENCES)
            + " |", "|---|" + "---|" * len(SEQUENCES)]
    for name, _ in VARIANTS.values():
        if name in results:
            cells = []
            for s in SEQUENCES:
                r = results[name].get(s)
                cells.append("n/a" if r is None else
                             f"{r['before']:.4f} -> {r['after']:.4f} ({100 * (r['after'] / r['before'] - 1):+.1f} %, "
                             f"{r['guard_step']}, {', '.join(r['guard_events']) or 'none'})")
            body.append(f"| {name} | " + " | ".join(cells) + " |")
    body += ["", "The objective at the truth (mean over the first 48 triplets):", "",
             "| sequence | case | L_ph | loss |", "|---|---|---|---|"]
    for s, o in results["objective"].items():
        for case in ("predicted depth, predicted poses", "true depth, true poses",
                     "predicted depth (median-scaled), true poses"):
            body.append(f"| {s} | {case} | {o[case]:.5f} | {o[case + ' (loss)']:.5f} |")
    rep = Report(__file__, "Test-time training from the zoo depth model: variants")
    rep.write(a.report, rep.render(body))
    print(f"wrote {a.report}")


if __name__ == "__main__":
    main()
