"""The training callback of the demo's ``fit`` runs (named by class path in their config:
:func:`c3f_demo.stages._fit_yaml`). It runs in the ``python -m c3f_models fit`` processes; the
demo's own process only reads its file (:func:`c3f_demo.progress.read_step_fraction`) and never
imports this module, nor Lightning."""

from __future__ import annotations

from pathlib import Path

import lightning as L


class ProgressFile(L.Callback):
    """Writes ``"STEP MAX_STEPS"`` to ``path`` after every training batch (read by the demo's ETA)."""

    def __init__(self, path: str) -> None:
        self.path = Path(path)

    def on_train_batch_end(self, trainer, pl_module, outputs, batch, batch_idx) -> None:
        self.path.write_text(f"{trainer.global_step} {trainer.max_steps}\n")


__all__ = ["ProgressFile"]
