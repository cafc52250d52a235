"""Exact resume through the CLI: ``fit`` N steps, then ``--ckpt_path last.ckpt``
to 2N, gives the weights of 2N uninterrupted steps at the same seed on CPU, bit for bit, and the
resumed run logs into the same TensorBoard version folder with its step numbers continuing.

With 4 training samples, batch 1 and ``limit_train_batches`` 4, an epoch is 4 steps: the
interruption falls in the middle of an epoch (the data loader's position and the epoch's order
must be restored) and the resumed run crosses epoch boundaries (validation included)."""

import random
from pathlib import Path

import numpy as np
import pytest
import torch
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

from c3f_models.cli import main
from c3f_models.resume import ExactResume, capture_rng_states, restore_rng_states, run_version_of
from datamodules.resumable import ResumableSampler

ROOT = Path(__file__).resolve().parents[1]


def _options(data: Path, out: Path) -> list[str]:
    return [
        "--config", "configs/trainer/cpu_smoke.yaml", "--config", "configs/depthnet/small.yaml",
        "--data.data_dir", str(data), "--data.frames.size", "[32, 32]", "--data.loader.batch_size", "1",
        "--trainer.default_root_dir", str(out), "--trainer.logger.init_args.save_dir", str(out),
        "--trainer.enable_progress_bar", "false", "--trainer.enable_model_summary", "false",
        "--trainer.limit_train_batches", "4", "--trainer.limit_val_batches", "1",
    ]


def _train_steps(run_dir: Path) -> list[int]:
    acc = EventAccumulator(str(run_dir))
    acc.Reload()
    return sorted(e.step for e in acc.Scalars("train/loss"))


def _resume_equals_uninterrupted(data: Path, tmp_path: Path, steps: int) -> None:
    whole, parts = tmp_path / "whole", tmp_path / "parts"
    main(["fit", *_options(data, whole), "--trainer.max_steps", str(2 * steps)])
    main(["fit", *_options(data, parts), "--trainer.max_steps", str(steps)])
    run = parts / "tb" / "version_0"
    main(["fit", *_options(data, parts), "--trainer.max_steps", str(2 * steps),
          "--ckpt_path", str(run / "checkpoints" / "last.ckpt")])
    a = torch.load(whole / "tb" / "version_0" / "checkpoints" / "last.ckpt", map_location="cpu", weights_only=True)
    b = torch.load(run / "checkpoints" / "last.ckpt", map_location="cpu", weights_only=True)
    assert a["global_step"] == b["global_step"] == 2 * steps
    differ = [k for k in a["state_dict"] if not torch.equal(a["state_dict"][k], b["state_dict"][k])]
    assert not differ, f"{len(differ)} of {len(a['state_dict'])} tensors differ, e.g. {differ[0]}"
    assert sorted(p.name for p in (parts / "tb").iterdir()) == ["version_0"], "the resumed run made a new version"
    assert _train_steps(run) == list(range(2 * steps)), "step numbers do not continue in the same run folder"


@pytest.mark.e2e
@pytest.mark.long
def test_fit_3_plus_3_resumed_equals_6_uninterrupted(plane_dataset, tmp_path, monkeypatch):
    monkeypatch.chdir(ROOT)
    _resume_equals_uninterrupted(plane_dataset, tmp_path, 3)


@pytest.mark.slow
def test_fit_10_plus_10_resumed_equals_20_uninterrupted(plane_dataset, tmp_path, monkeypatch):
    monkeypatch.chdir(ROOT)
    _resume_equals_uninterrupted(plane_dataset, tmp_path, 10)


def test_sampler_resumes_mid_epoch_with_the_epochs_order_and_draws():
    whole = ResumableSampler(10, seed=3, keyed=True)
    whole.set_epoch(2)
    expected = list(whole)
    assert sorted(i for i, _ in expected) == list(range(10)) and expected != [(i, d) for i, d in sorted(expected)]
    state = whole.state_dict(position=4, epoch=2)
    resumed = ResumableSampler(10, seed=0, keyed=True)
    resumed.load_state_dict(state)
    resumed.set_epoch(3)  # Lightning's counter may say otherwise before the first fetch: the saved epoch wins
    assert list(resumed) == expected[4:]
    resumed.set_epoch(2)
    assert list(resumed) == expected, "only the first iteration after loading starts in mid-epoch"
    other = ResumableSampler(10, seed=3)
    other.set_epoch(3)
    assert list(other) != [i for i, _ in expected], "every epoch has its own order"
    with pytest.raises(ValueError, match="10 samples per epoch, this one has 9"):
        ResumableSampler(9, seed=3).load_state_dict(state)


def test_rng_states_round_trip_and_restore_at_the_first_step():
    torch.manual_seed(5)
    np.random.seed(5)
    random.seed(5)
    saved = capture_rng_states()
    expected = (torch.rand(3), np.random.rand(3), random.random())
    callback = ExactResume()
    callback.load_state_dict({"rng": saved})
    torch.rand(7), np.random.rand(7), random.random()  # what the resumed run draws before its first step
    assert callback.state_dict()["rng"] is saved
    callback.on_train_batch_start(None, None, None, 0)
    got = (torch.rand(3), np.random.rand(3), random.random())
    assert torch.equal(got[0], expected[0]) and np.array_equal(got[1], expected[1]) and got[2] == expected[2]
    restore_rng_states(saved)
    assert torch.equal(torch.rand(3), expected[0])
    callback.on_train_batch_start(None, None, None, 0)  # a checkpoint in mid-step holds the step's start
    at_start = capture_rng_states()
    torch.rand(2)
    assert torch.equal(callback.state_dict()["rng"]["torch"], at_start["torch"])


def test_run_version_of(tmp_path):
    ckpt = tmp_path / "runs" / "tb" / "version_3" / "checkpoints" / "last.ckpt"
    assert run_version_of(ckpt, tmp_path / "runs", "tb") == 3
    mine = tmp_path / "runs" / "tb" / "mine" / "checkpoints" / "a.ckpt"
    assert run_version_of(mine, tmp_path / "runs", "tb") == "mine"
    assert run_version_of(ckpt, tmp_path / "other", "tb") is None
    assert run_version_of(tmp_path / "elsewhere" / "last.ckpt", tmp_path / "runs", "tb") is None


def test_contrafeat_training_gaps_follow_the_seed_not_the_global_rng(sim_dataset):
    """ContraFeat's random frame gap comes from the keyed sampler's draw: the same seed and epoch
    give the same batches whatever the global RNG did in between (so a fetch ahead, or a resume,
    does not change them)."""
    from datamodules.pairs import ContraFeatDataModule

    def gaps(draws_between: int) -> list[int]:
        torch.manual_seed(11)
        dm = ContraFeatDataModule(str(sim_dataset), frames={"size": [16, 16], "specular": False},
                                  sampling={"gaps": [1, 2, 3]}, split={"val_fraction": 0.0, "test_fraction": 0.0},
                                  loader={"batch_size": 2})
        dm.setup("fit")
        loader = dm.train_dataloader()
        torch.rand(draws_between)
        return [g for batch in loader for g in batch["gap"].tolist()]

    first = gaps(1)
    assert first == gaps(50)
    assert len(set(first)) > 1
