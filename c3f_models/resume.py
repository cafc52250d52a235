"""What an exact resume needs beyond Lightning's checkpoint: the RNG states, and the run folder to continue.

:class:`ExactResume` (a callback of every :class:`c3f_models.trainer.C3FTrainer`) puts the torch
(CPU and CUDA), numpy and Python RNG states in each checkpoint and sets them again at the first
training step of a resumed run, so the draws of that step are those the uninterrupted run made.
The states saved are those at the end of the last finished training step; a checkpoint written
in the middle of a step (Ctrl-C) holds the states at that step's start, since the resumed run
does that step again. Nothing else of a run draws from the global RNG (the loaders have their
own generators, :mod:`datamodules.resumable`), so those are the states the next step starts from.

:func:`run_version_of` finds the TensorBoard run folder a ``--ckpt_path`` belongs to, so that a
resumed run logs into it (same version, continuing step numbers) instead of a new version.
"""

from __future__ import annotations

import random
from pathlib import Path
from typing import Any

import lightning as L
import numpy as np
import torch
from lightning.pytorch.callbacks import Callback

#: the folder name of a run's checkpoints inside its TensorBoard version folder (Lightning's)
CHECKPOINTS_DIR = "checkpoints"


def capture_rng_states() -> dict[str, Any]:
    """The torch CPU/CUDA, numpy and Python RNG states, as tensors, ints and lists (the safe
    unpickler, ``weights_only=True``, reads them back)."""
    kind, keys, pos, has_gauss, cached = np.random.get_state()
    version, internal, gauss_next = random.getstate()
    return {
        "torch": torch.get_rng_state(),
        "cuda": torch.cuda.get_rng_state_all() if torch.cuda.is_available() else [],
        "numpy": {"kind": str(kind), "keys": torch.from_numpy(keys.astype(np.int64)), "pos": int(pos),
                  "has_gauss": int(has_gauss), "cached": float(cached)},
        "python": {"version": int(version), "internal": list(internal), "gauss_next": gauss_next},
    }


def restore_rng_states(states: dict[str, Any]) -> None:
    """Set the RNG states :func:`capture_rng_states` returned (CUDA ones only where CUDA is there)."""
    torch.set_rng_state(states["torch"])
    if states.get("cuda") and torch.cuda.is_available():
        torch.cuda.set_rng_state_all(states["cuda"])
    n = states["numpy"]
    np.random.set_state((n["kind"], n["keys"].numpy().astype(np.uint32), n["pos"], n["has_gauss"], n["cached"]))
    p = states["python"]
    random.setstate((p["version"], tuple(p["internal"]), p["gauss_next"]))


class ExactResume(Callback):
    """Saves the RNG states in every checkpoint; a resumed run sets them at its first training step.

    At that step the step number the loggers use is also set to the trainer's ``global_step``:
    Lightning's own count is one ahead after resuming a checkpoint saved at an epoch's end or in
    mid-step (Ctrl-C), which leaves a gap in the TensorBoard steps of the continued run.
    """

    def __init__(self) -> None:
        self._step_start: dict[str, Any] | None = None  # states at the start of the running step
        self._in_step = False
        self._to_restore: dict[str, Any] | None = None
        self._first_step = True

    def on_train_start(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        self._first_step = True

    def on_train_batch_start(self, trainer: L.Trainer, pl_module: L.LightningModule, batch: Any,
                             batch_idx: int) -> None:
        if self._first_step and trainer is not None:
            trainer.fit_loop.epoch_loop._batches_that_stepped = trainer.global_step  # one optimizer: the same count
        self._first_step = False
        if self._to_restore is not None:
            restore_rng_states(self._to_restore)
            self._to_restore = None
        self._step_start, self._in_step = capture_rng_states(), True

    def on_train_batch_end(self, trainer: L.Trainer, pl_module: L.LightningModule, outputs: Any, batch: Any,
                           batch_idx: int) -> None:
        self._in_step = False

    def state_dict(self) -> dict[str, Any]:
        if self._to_restore is not None:  # saved before the resumed run made a step: still the loaded states
            return {"rng": self._to_restore}
        return {"rng": self._step_start if self._in_step else capture_rng_states()}

    def load_state_dict(self, state_dict: dict[str, Any]) -> None:
        self._to_restore = state_dict.get("rng")


def run_version_of(ckpt_path: str | Path, save_dir: str | Path, name: str) -> int | str | None:
    """The TensorBoardLogger ``version`` whose folder holds ``ckpt_path`` (``<save_dir>/<name>/<version
    folder>/checkpoints/<file>``): the number of a ``version_N`` folder, else the folder's name;
    None when the checkpoint is not inside that logger's folder."""
    ckpt = Path(ckpt_path).resolve()
    run = ckpt.parent.parent
    if ckpt.parent.name != CHECKPOINTS_DIR or run.parent != (Path(save_dir) / (name or "")).resolve():
        return None
    number = run.name.removeprefix("version_")
    return int(number) if run.name.startswith("version_") and number.isdigit() else run.name


__all__ = ["CHECKPOINTS_DIR", "ExactResume", "capture_rng_states", "restore_rng_states", "run_version_of"]
