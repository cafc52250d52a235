"""A guard for self-supervised test-time training: no collapse to a flat depth, and the best
weights by a criterion that needs no ground truth.

The paper's objective, run on one sequence from good weights, can drift to a flat depth (its
depth-consistency term is lowest there; docs/lab_notes/2026-11-22-depthnet-diagnosis.md). The guard
watches ``train/depth_cv`` (spatial std / mean of the predicted depth, logged every step by
DepthNet) and ``train/ph`` (the minimum-reprojection photometric term, which a flat depth does
not lower). Every ``every`` steps it compares the recent mean spread with the spread of the
first ``window`` steps:

- below ``min_spread_ratio`` of it: the depth is collapsing. The weights go back to the best
  healthy snapshot and training stops;
- otherwise the weights are a healthy snapshot; the one with the lowest mean photometric term
  (over the steps since the previous snapshot) is the best so far.

When training ends, the best snapshot's weights are put back (before the ``ModelCheckpoint``
writes ``last.ckpt``: Lightning runs checkpoint callbacks last), so the run's result is the
best healthy state, never a collapsed one. What it did is in ``guard.json`` beside the
checkpoints and in TensorBoard (``ttt_guard/*``). Snapshots are kept in memory (one copy of
the weights).
"""

from __future__ import annotations

import copy
import json
from pathlib import Path

import lightning as L
import torch
from lightning.pytorch.callbacks import Callback

from c3f_core.errors import InputError


class TestTimeGuard(Callback):
    """Stop and roll back on a collapsing depth; keep the best weights by the photometric term.

    Args:
        min_spread_ratio: stop when the recent mean ``depth_cv`` falls below this fraction of the
            first ``window`` steps' mean (0.7: 30 % flatter).
        window: steps of the reference spread and of each recent mean.
        every: steps between two checks (and snapshots).
    """

    __test__ = False  # not a pytest class

    def __init__(self, min_spread_ratio: float = 0.7, window: int = 10, every: int = 10) -> None:
        if not 0.0 < min_spread_ratio < 1.0:
            raise InputError(f"TestTimeGuard.min_spread_ratio must be in (0, 1), got {min_spread_ratio}")
        if window < 1 or every < 1:
            raise InputError(f"TestTimeGuard.window and every must be >= 1, got {window}, {every}")
        self.min_spread_ratio, self.window, self.every = min_spread_ratio, window, every
        self.spreads: list[float] = []
        self.photometric: list[float] = []
        self.reference: float | None = None
        self.best: dict | None = None  # {"step", "ph", "state"}
        self.events: list[dict] = []

    # ------------------------------------------------------------------ bookkeeping
    def on_train_batch_end(self, trainer: L.Trainer, pl_module: L.LightningModule, outputs, batch, batch_idx) -> None:
        metrics = trainer.callback_metrics
        if "train/depth_cv" not in metrics or "train/ph" not in metrics:
            return
        self.spreads.append(float(metrics["train/depth_cv"]))
        self.photometric.append(float(metrics["train/ph"]))
        n = len(self.spreads)
        if self.reference is None:
            if n >= self.window:
                self.reference = sum(self.spreads[: self.window]) / self.window
                self._snapshot(trainer, pl_module)
            return
        if n % self.every:
            return
        recent = sum(self.spreads[-self.window:]) / self.window
        ratio = recent / max(self.reference, 1e-12)
        pl_module.log("ttt_guard/spread_ratio", ratio, on_step=True, on_epoch=False)
        if ratio < self.min_spread_ratio:
            self.events.append({"step": trainer.global_step, "event": "collapse", "spread_ratio": ratio})
            self._restore(pl_module)
            trainer.should_stop = True
        else:
            self._snapshot(trainer, pl_module)

    def _snapshot(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        """Keep the weights if their recent photometric term is the lowest so far."""
        ph = sum(self.photometric[-self.every:]) / len(self.photometric[-self.every:])
        if self.best is None or ph < self.best["ph"]:
            self.best = {"step": int(trainer.global_step), "ph": ph,
                         "state": copy.deepcopy({k: v.detach().cpu() for k, v in pl_module.state_dict().items()})}

    def _restore(self, pl_module: L.LightningModule) -> None:
        if self.best is not None:
            pl_module.load_state_dict(self.best["state"])
            self.events.append({"event": "restored", "from_step": self.best["step"], "ph": self.best["ph"]})

    def on_train_epoch_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        epochs = trainer.max_epochs if trainer.max_epochs is not None and trainer.max_epochs > 0 else None
        last = (trainer.should_stop or 0 < trainer.max_steps <= trainer.global_step
                or (epochs is not None and trainer.current_epoch + 1 >= epochs))
        if not last or any(e["event"] == "collapse" for e in self.events):
            return
        self._restore(pl_module)

    def on_train_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        folder = Path(getattr(trainer.checkpoint_callback, "dirpath", None) or trainer.default_root_dir)
        report = {"reference_spread": self.reference, "min_spread_ratio": self.min_spread_ratio,
                  "best_step": None if self.best is None else self.best["step"],
                  "best_photometric": None if self.best is None else self.best["ph"],
                  "steps": len(self.spreads), "events": self.events}
        if trainer.is_global_zero:
            folder.mkdir(parents=True, exist_ok=True)
            (folder / "guard.json").write_text(json.dumps(report, indent=2) + "\n")
        self.report = report


def state_equal(a: dict[str, torch.Tensor], b: dict[str, torch.Tensor]) -> bool:
    """True when two state dicts hold the same tensors (for tests and checks)."""
    return a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)


__all__ = ["TestTimeGuard", "state_equal"]
