"""End to end through the CLI: a smoke fit writes TensorBoard events, the saved config and a
checkpoint, and a second run resumes from that checkpoint (``--ckpt_path``)."""

from pathlib import Path

import pytest
import torch
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

from c3f_models.cli import main

ROOT = Path(__file__).resolve().parents[1]


def _scalar_steps(run_dir: Path, tag: str) -> list[int]:
    acc = EventAccumulator(str(run_dir))
    acc.Reload()
    return [e.step for e in acc.Scalars(tag)] if tag in acc.Tags()["scalars"] else []


@pytest.mark.e2e
def test_smoke_fit_then_resume(plane_dataset, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(ROOT)
    common = [
        "--config", "configs/trainer/cpu_smoke.yaml",
        "--config", "configs/depthnet/small.yaml",
        "--data.data_dir", str(plane_dataset),
        "--data.frames.size", "[32, 32]",
        "--data.loader.batch_size", "2",
        "--trainer.default_root_dir", str(tmp_path),
        "--trainer.logger.init_args.save_dir", str(tmp_path),
        "--trainer.enable_progress_bar", "false",
    ]
    main(["fit", *common, "--trainer.max_steps", "2"])
    first = tmp_path / "tb" / "version_0"
    assert list(first.glob("events.out.tfevents*")), "no TensorBoard events written"
    assert (first / "config.yaml").is_file(), "config not saved next to the logs"
    ckpt = first / "checkpoints" / "last.ckpt"
    assert ckpt.is_file()
    assert torch.load(ckpt, map_location="cpu", weights_only=True)["global_step"] == 2
    assert _scalar_steps(first, "train/loss"), "no training loss logged"

    # an override the resumed run would drop is refused in one line, before anything runs
    with pytest.raises(SystemExit) as exc:
        main(["fit", *common, "--trainer.max_steps", "4", "--ckpt_path", str(ckpt), "--model.loss.lambda_dc", "0.5"])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "a resumed run keeps the checkpoint's model options" in err[0]
    assert "model.loss.lambda_dc: 0.1 in the checkpoint, 0.5 given" in err[0]
    assert not (tmp_path / "tb" / "version_1").exists()

    main(["fit", *common, "--trainer.max_steps", "4", "--ckpt_path", str(ckpt)])
    # the resumed run continues the same run folder, its step numbers following the first run's
    assert not (tmp_path / "tb" / "version_1").exists()
    steps = _scalar_steps(first, "train/loss")
    assert sorted(steps) == [0, 1, 2, 3], f"the second run did not continue at step 2: logged steps {steps}"
    assert torch.load(ckpt, map_location="cpu", weights_only=True)["global_step"] == 4


@pytest.mark.e2e
def test_ctrl_c_during_fit_saves_a_checkpoint_and_is_one_line(plane_dataset, tmp_path, monkeypatch, capsys):
    """Ctrl-C (a KeyboardInterrupt in a training step): the steps done so far are saved to
    checkpoints/interrupted.ckpt, one error line says where, exit 130; the run resumes from it."""
    from c3f_models.depth.module import DepthNet

    monkeypatch.chdir(ROOT)
    common = [
        "--config", "configs/trainer/cpu_smoke.yaml", "--config", "configs/depthnet/small.yaml",
        "--data.data_dir", str(plane_dataset), "--data.frames.size", "[32, 32]", "--data.loader.batch_size", "2",
        "--trainer.default_root_dir", str(tmp_path), "--trainer.logger.init_args.save_dir", str(tmp_path),
        "--trainer.enable_progress_bar", "false",
    ]
    step = DepthNet.training_step

    def interrupted_step(self, batch, batch_idx):
        if self.global_step == 2:
            raise KeyboardInterrupt
        return step(self, batch, batch_idx)

    monkeypatch.setattr(DepthNet, "training_step", interrupted_step)
    with pytest.raises(SystemExit) as exc:
        main(["fit", *common, "--trainer.max_steps", "4"])
    assert exc.value.code == 130
    ckpt = tmp_path / "tb" / "version_0" / "checkpoints" / "interrupted.ckpt"
    err = [line for line in capsys.readouterr().err.strip().splitlines() if line.startswith("error:")]
    assert err == [f"error: interrupted at step 2; checkpoint saved: {ckpt} (resume with --ckpt_path {ckpt})"]
    assert torch.load(ckpt, map_location="cpu", weights_only=True)["global_step"] == 2
    monkeypatch.setattr(DepthNet, "training_step", step)
    main(["fit", *common, "--trainer.max_steps", "4", "--ckpt_path", str(ckpt)])
    steps = _scalar_steps(tmp_path / "tb" / "version_0", "train/loss")
    assert sorted(steps) == [0, 1, 2, 3], f"logged steps {steps}"
    assert not (tmp_path / "tb" / "version_1").exists()
