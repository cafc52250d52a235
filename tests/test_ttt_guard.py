"""The test-time training guard: a collapsing depth spread stops the run and puts back the best
healthy weights; a healthy run ends on the snapshot with the lowest photometric term."""

from __future__ import annotations

import json
from types import SimpleNamespace

import pytest
import torch
from torch import nn

from c3f_core.errors import InputError
from c3f_models.depth.ttt_guard import TestTimeGuard, state_equal


class _Module(nn.Linear):
    def __init__(self) -> None:
        super().__init__(2, 1)

    def log(self, *args, **kwargs) -> None:
        pass


def _trainer(tmp_path, max_steps=1000):
    return SimpleNamespace(callback_metrics={}, global_step=0, should_stop=False, max_steps=max_steps,
                           max_epochs=None, current_epoch=0, checkpoint_callback=SimpleNamespace(dirpath=tmp_path),
                           default_root_dir=tmp_path, is_global_zero=True)


def _steps(guard, trainer, module, spreads, photometric):
    for cv, ph in zip(spreads, photometric):
        trainer.global_step += 1
        with torch.no_grad():
            module.weight += 1.0  # the weights change every step
        trainer.callback_metrics = {"train/depth_cv": torch.tensor(cv), "train/ph": torch.tensor(ph)}
        guard.on_train_batch_end(trainer, module, None, None, trainer.global_step)
        if trainer.should_stop:
            break


def test_collapse_stops_and_restores_the_best_healthy_weights(tmp_path):
    guard, trainer, module = TestTimeGuard(0.7, window=5, every=5), _trainer(tmp_path), _Module()
    spreads = [0.5] * 20 + [0.1] * 20  # flat from step 21
    photometric = [0.10] * 5 + [0.08] * 5 + [0.09] * 30  # best snapshot: step 10
    _steps(guard, trainer, module, spreads, photometric)
    assert trainer.should_stop and trainer.global_step == 25
    assert guard.best["step"] == 10
    assert state_equal(module.state_dict(), guard.best["state"])
    assert float(module.weight[0, 0]) == pytest.approx(float(guard.best["state"]["weight"][0, 0]))
    guard.on_train_end(trainer, module)
    report = json.loads((tmp_path / "guard.json").read_text())
    assert [e["event"] for e in report["events"]] == ["collapse", "restored"] and report["best_step"] == 10


def test_healthy_run_ends_on_the_lowest_photometric_snapshot(tmp_path):
    guard, trainer, module = TestTimeGuard(0.7, window=5, every=5), _trainer(tmp_path, max_steps=30), _Module()
    photometric = [0.10] * 10 + [0.05] * 5 + [0.07] * 15  # best: the snapshot at step 15
    _steps(guard, trainer, module, [0.5] * 30, photometric)
    assert not trainer.should_stop
    guard.on_train_epoch_end(trainer, module)  # the run's end: max_steps reached
    assert guard.best["step"] == 15 and state_equal(module.state_dict(), guard.best["state"])


def test_settings_checked():
    with pytest.raises(InputError, match="min_spread_ratio"):
        TestTimeGuard(1.5)
