"""A refused ``fit`` leaves no run folder behind: what the refused run created under
the logger's folder is removed, and a resumed run's existing folder is left as it was."""

from pathlib import Path

import pytest
import torch

from c3f_models.cli import main

ROOT = Path(__file__).resolve().parents[1]


def _options(data: Path, out: Path) -> list[str]:
    return [
        "--config", "configs/trainer/cpu_smoke.yaml", "--config", "configs/depthnet/small.yaml",
        "--data.data_dir", str(data), "--data.frames.size", "[32, 32]", "--data.loader.batch_size", "2",
        "--trainer.default_root_dir", str(out), "--trainer.logger.init_args.save_dir", str(out / "logs"),
        "--trainer.enable_progress_bar", "false", "--trainer.enable_model_summary", "false",
    ]


def _files(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def _refused(args: list[str], capsys) -> str:
    with pytest.raises(SystemExit) as exc:
        main(args)
    assert exc.value.code == 2
    errors = [line for line in capsys.readouterr().err.splitlines() if line.startswith("error:")]
    assert len(errors) == 1, errors
    return errors[0]


def test_refused_init_weights_leaves_no_log_folder(plane_dataset, tmp_path, monkeypatch, capsys):
    """The weights are refused in the model's setup, after Lightning made tb/version_0 (events,
    config.yaml): it is removed, and so is the logger's save_dir the run created."""
    monkeypatch.chdir(ROOT)
    wrong = tmp_path / "wrong.ckpt"
    torch.save({"state_dict": {"not.a.key": torch.zeros(1)}}, wrong)
    err = _refused(["fit", *_options(plane_dataset, tmp_path), "--trainer.max_steps", "1",
                    "--model.init_weights", str(wrong)], capsys)
    assert "model.init_weights" in err and "does not fit" in err
    assert not (tmp_path / "logs").exists(), sorted(map(str, tmp_path.rglob("*")))


@pytest.mark.e2e
def test_refused_resume_leaves_the_run_folder_as_it_was(plane_dataset, tmp_path, monkeypatch, capsys):
    """A resumed run writes into its checkpoint's folder; refused there (an unknown training
    sequence, found in the data module's setup), the folder keeps exactly its files."""
    monkeypatch.chdir(ROOT)
    main(["fit", *_options(plane_dataset, tmp_path), "--trainer.max_steps", "1"])
    run = tmp_path / "logs" / "tb" / "version_0"
    before = _files(run)
    err = _refused(["fit", *_options(plane_dataset, tmp_path), "--trainer.max_steps", "2",
                    "--ckpt_path", str(run / "checkpoints" / "last.ckpt"), "--data.split.train", '["nowhere"]'], capsys)
    assert "data.split.train: unknown sequence 'nowhere'" in err
    assert _files(run) == before
    assert sorted(p.name for p in run.parent.iterdir()) == ["version_0"]
