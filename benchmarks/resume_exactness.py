"""Is a resumed ``fit`` the same as an uninterrupted one? Weight differences per tensor.

Runs, through the CLI in-process on CPU at the same seed: ``fit`` for 2N steps; ``fit`` for N
steps and then ``--ckpt_path .../last.ckpt`` to 2N. Data: three tiny simulator sequences (one
trains, 4 samples at batch 1, ``limit_train_batches`` 4: an epoch is 4 steps, so N = 10 stops
in the middle of an epoch). Prints, over the model's tensors (weights and buffers): how many
differ, the largest absolute difference, the median over tensors of the median relative
difference |a - b| / (|a| + 1e-12), and the run folders the resumed run logged into.

    python -m benchmarks.resume_exactness --work /tmp/resume_bench --steps 10 \
        --report benchmarks/results/resume_exactness.md
"""

from __future__ import annotations

import argparse
import shutil
from pathlib import Path

import torch

from benchmarks.common.report import Report
from c3f_models.cli import main as cli

ROOT = Path(__file__).resolve().parents[1]


def make_data(folder: Path) -> Path:
    from datamodules.synthetic.fixture import make_tiny_sequence

    for k in range(3):
        if not (folder / f"sim{k}").is_dir():
            make_tiny_sequence(folder / f"sim{k}", frames=6, size=48, seed=k)
    return folder


def fit(data: Path, out: Path, steps: int, ckpt: Path | None = None) -> None:
    cli(["fit", "--config", "configs/trainer/cpu_smoke.yaml", "--config", "configs/depthnet/small.yaml",
         "--data.data_dir", str(data), "--data.frames.size", "[32, 32]", "--data.loader.batch_size", "1",
         "--trainer.default_root_dir", str(out), "--trainer.logger.init_args.save_dir", str(out),
         "--trainer.enable_progress_bar", "false", "--trainer.enable_model_summary", "false",
         "--trainer.limit_train_batches", "4", "--trainer.limit_val_batches", "1",
         "--trainer.max_steps", str(steps), *(["--ckpt_path", str(ckpt)] if ckpt else [])])


def final_checkpoint(out: Path, step: int) -> Path:
    """The ``last.ckpt`` under ``out/tb/*/checkpoints`` that reached ``step``."""
    for path in sorted(out.glob("tb/*/checkpoints/last.ckpt")):
        if torch.load(path, map_location="cpu", weights_only=True)["global_step"] == step:
            return path
    raise SystemExit(f"error: no checkpoint of step {step} under {out}")


def differences(a: dict[str, torch.Tensor], b: dict[str, torch.Tensor]) -> list[tuple[str, float, float]]:
    """(name, max |a - b|, median |a - b| / (|a| + 1e-12)) of every tensor of ``a``."""
    out = []
    for name, x in a.items():
        x, y = x.double(), b[name].double()
        diff = (x - y).abs()
        rel = diff / (x.abs() + 1e-12)
        out.append((name, float(diff.max()) if diff.numel() else 0.0, float(rel.median()) if rel.numel() else 0.0))
    return out


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--work", type=Path, default=Path("/tmp/resume_bench"), help="scratch folder (rewritten)")
    parser.add_argument("--steps", type=int, default=10, help="N: steps before the resume (the whole run: 2N)")
    parser.add_argument("--report", type=Path, help="markdown file for the result")
    args = parser.parse_args(argv)
    data = make_data(args.work / "data")
    whole, parts = args.work / "whole", args.work / "parts"
    for folder in (whole, parts):
        shutil.rmtree(folder, ignore_errors=True)
    n = args.steps
    fit(data, whole, 2 * n)
    fit(data, parts, n)
    fit(data, parts, 2 * n, parts / "tb" / "version_0" / "checkpoints" / "last.ckpt")
    a = torch.load(final_checkpoint(whole, 2 * n), map_location="cpu", weights_only=True)["state_dict"]
    resumed = final_checkpoint(parts, 2 * n)
    b = torch.load(resumed, map_location="cpu", weights_only=True)["state_dict"]
    rows = differences(a, b)
    differ = [r for r in rows if r[1] > 0]
    rel = sorted(r[2] for r in rows)
    versions = sorted(p.name for p in (parts / "tb").iterdir())
    lines = [
        f"- {n} + {n} steps resumed vs {2 * n} uninterrupted, DepthNet small, CPU, seed 42, 32x32 frames, batch 1, "
        "4 steps per epoch (the resume falls in mid-epoch).",
        f"- Tensors that differ: {len(differ)} of {len(rows)}; largest |difference|: {max(r[1] for r in rows):.3g}; "
        f"median over tensors of the median relative difference: {rel[len(rel) // 2]:.3g}.",
        f"- Run folders of the resumed pair: {', '.join(versions)} (the resumed run's checkpoint: "
        f"{resumed.relative_to(parts)}).",
        "", "Largest differences:", "", "| tensor | max abs | median rel |", "|---|---|---|",
        *[f"| `{name}` | {mx:.3g} | {md:.3g} |" for name, mx, md in sorted(differ, key=lambda r: -r[1])[:8]],
    ]
    if not differ:
        lines = lines[:3] + ["", "Every tensor is equal (torch.equal): the resume is bit-exact."]
    report = Report(__file__, "Resume exactness: resumed vs uninterrupted fit", argv)
    text = report.render(lines)
    print(text)
    if args.report:
        report.write(args.report, text)


if __name__ == "__main__":
    main()
