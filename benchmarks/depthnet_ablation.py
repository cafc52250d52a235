"""DepthNet ablation: the full C3Fusion objective vs the Monodepth2 baseline, trained identically.

Both runs use the same simulator sequences, seed, steps, batch size and network (the small
CPU variant unless --full-size); only the loss switches differ (configs/depthnet/small.yaml
vs small_monodepth2.yaml). Each is then tested on held-out sequences with the project's
metric function (per-image median scaling). Sq Rel and RMSE are printed in centimetres,
as the paper's table is. Training throughput is images/s over the whole fit (data loading
included).

    python benchmarks/depthnet_ablation.py --data runs/bench/depth_data --steps 400

Writes benchmarks/results/depthnet_ablation.md (numbers + the command line).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
METRICS = ("abs_rel", "sq_rel", "rmse", "rmse_log", "a1", "a2", "a3")
IN_CM = {"sq_rel": 100.0, "rmse": 100.0}  # metres -> cm for the table (Sq Rel has units of depth)


def generate(data: Path, names: list[str], frames: int, size: int) -> None:
    for k, name in enumerate(names):
        out = data / name
        if (out / "camera.json").is_file():
            continue
        preset = f"seq{k % 8 + 1}"
        cmd = [sys.executable, "-m", "datamodules.synthetic", "generate", "--preset", preset, "--frames", str(frames),
               "--size", str(size), "--seed", str(100 + k), "--out", str(out), "--no-progress", "--overwrite"]
        subprocess.run(cmd, check=True, cwd=ROOT)


def run(config: str, data: Path, train: list[str], test: list[str], steps: int, batch: int, size: int, root: Path) -> dict:
    from c3f_models.cli import main

    common = [
        "--config", "configs/trainer/cpu_smoke.yaml", "--config", config,
        "--data.data_dir", str(data), "--data.train", json.dumps(train), "--data.val", "[]",
        "--data.test", json.dumps(test), "--data.size", f"[{size}, {size}]", "--data.batch_size", str(batch),
        "--trainer.default_root_dir", str(root), "--trainer.logger.init_args.save_dir", str(root),
        "--trainer.enable_progress_bar", "false", "--seed_everything", "7",
    ]
    t0 = time.perf_counter()
    cli = main(["fit", *common, "--trainer.max_steps", str(steps), "--trainer.limit_train_batches", "1.0",
                "--trainer.max_epochs", "-1", "--trainer.limit_val_batches", "0"])
    fit_s = time.perf_counter() - t0
    ckpt = Path(cli.trainer.checkpoint_callback.last_model_path)
    cli = main(["test", *common, "--ckpt_path", str(ckpt), "--trainer.limit_test_batches", "1.0"])
    metrics = {k: float(cli.trainer.callback_metrics[f"test/{k}"]) for k in METRICS}
    metrics["images_per_s"] = steps * batch / fit_s
    return metrics


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", type=Path, default=ROOT / "runs/bench/depth_data")
    ap.add_argument("--train-seqs", type=int, default=4)
    ap.add_argument("--test-seqs", type=int, default=2)
    ap.add_argument("--frames", type=int, default=200)
    ap.add_argument("--size", type=int, default=128)
    ap.add_argument("--steps", type=int, default=400)
    ap.add_argument("--batch", type=int, default=4)
    ap.add_argument("--threads", type=int, default=1, help="torch intra-op threads (1 is fastest on a shared 2-core machine)")
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks/results/depthnet_ablation.md")
    a = ap.parse_args()
    import torch

    torch.set_num_threads(a.threads)

    train = [f"train{k}" for k in range(a.train_seqs)]
    test = [f"test{k}" for k in range(a.test_seqs)]
    generate(a.data, train + test, a.frames, a.size)
    results = {}
    for name, cfg in (("Monodepth2 baseline", "configs/depthnet/small_monodepth2.yaml"),
                      ("C3Fusion (full)", "configs/depthnet/small.yaml")):
        results[name] = run(cfg, a.data, train, test, a.steps, a.batch, a.size, a.data.parent / name.split()[0].lower())

    head = "| method | AbsRel | SqRel (cm) | RMSE (cm) | RMSElog | δ1 | δ2 | δ3 | train img/s |\n|---|---|---|---|---|---|---|---|---|\n"
    rows = "".join(
        f"| {n} | " + " | ".join(f"{m[k] * IN_CM.get(k, 1.0):.4f}" for k in METRICS) + f" | {m['images_per_s']:.2f} |\n"
        for n, m in results.items()
    )
    base, full = results["Monodepth2 baseline"], results["C3Fusion (full)"]
    ratio = f"Sq Rel full / baseline = {full['sq_rel'] / base['sq_rel']:.3f} (paper: 0.049 / 0.058 = 0.845)\n"
    cmd = "python " + " ".join([str(Path(sys.argv[0]).relative_to(ROOT) if Path(sys.argv[0]).is_absolute() else sys.argv[0]), *sys.argv[1:]])
    text = (
        "# DepthNet ablation: full objective vs Monodepth2 baseline\n\n"
        f"Command: `{cmd}`\n\n"
        f"Setup: ResNet18 without DCN (the small CPU variant), {a.size}x{a.size}, batch {a.batch}, {a.steps} steps each, "
        f"seed 7, CPU ({a.threads} torch thread). Data: simulator, {a.train_seqs} training sequences and {a.test_seqs} held-out test sequences of "
        f"{a.frames} frames (presets seq1.., seeds 100+k). Metrics on the test sequences only, per-image median scaling.\n\n"
        + head + rows + "\n" + ratio
    )
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(text)
    print(text)


if __name__ == "__main__":
    main()
