"""Test-time training of a zoo depth entry on one sequence, then the depth graph's ONNX export:
what the zoo protocol's ``ttt`` and ``real`` sections and ``zoo real --ttt-steps`` run.

The paper's objective (``configs/depthnet/ttt.yaml`` + ``configs/depthnet/paper_objective.yaml``:
no ground truth), batch 4, the guard on; each step a ``python -m c3f_models`` command in the
repository, so a run is the one a user would type.
"""

from __future__ import annotations

from pathlib import Path

from c3f_models.zoo.train import run_module


def tune_and_export(model: str, config: Path, seq: Path, run: Path, steps: int, *,
                    extra: tuple[str, ...] = ()) -> Path:
    """Test-time train ``model`` (``zoo:NAME`` or a weights file; ``config`` the entry's
    config.yaml) on the sequence ``seq`` for ``steps`` steps of batch 4 with the paper's objective
    (ttt.yaml + paper_objective.yaml, then the ``extra`` options), into ``run``; export its depth
    graph to ``run/onnx/depthnet.onnx``; returns the checkpoint folder (``guard.json`` is there)."""
    run_module(["-m", "c3f_models", "fit", "--config", str(config), "--config", "configs/depthnet/ttt.yaml",
                "--config", "configs/depthnet/paper_objective.yaml", *extra, "--model.init_weights", str(model),
                "--data.loader.batch_size", "4", "--data.data_dir", str(seq), "--trainer.max_epochs", "-1",
                "--trainer.max_steps", str(steps), "--trainer.default_root_dir", str(run),
                "--trainer.logger.init_args.save_dir", str(run), "--trainer.logger.init_args.version", "0",
                "--trainer.enable_progress_bar", "false"], f"ttt {seq.name}")
    checkpoints = run / "tb" / "version_0" / "checkpoints"
    run_module(["-m", "c3f_models", "export", "--config", str(run / "tb" / "version_0" / "config.yaml"),
                "--ckpt_path", str(checkpoints / "last.ckpt"), "--output_dir", str(run / "onnx"), "--graphs",
                "[depth]", "--frames", str(seq)], f"export ttt {seq.name}")
    return checkpoints


__all__ = ["tune_and_export"]
