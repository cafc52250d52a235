"""What DepthNet and ContraFeat share: the optimiser and schedule, ``init_weights``, plain hyper-parameters."""

from __future__ import annotations

from collections.abc import MutableMapping
from pathlib import Path

import lightning as L
import torch

from c3f_core.errors import InputError
from c3f_core.settings import settings_as_dicts
from c3f_models.checkpoints import load_weights, read_checkpoint_weights
from c3f_models.config import ADAM_BETAS, OptimConfig
from c3f_slam.models import zoo

INIT_WEIGHTS_OPTION = "model.init_weights"


class C3FModule(L.LightningModule):
    """LightningModule base: AdamW + MultiStepLR from an :class:`OptimConfig`, start weights from a checkpoint.

    Args:
        optim: optimiser and learning-rate schedule.
        init_weights: checkpoint (or ``.safetensors`` state dict, or ``zoo:NAME``: the zoo
            entry's weights) whose weights initialise the model at the start of ``fit`` (strict;
            optimiser and epoch not resumed; for test-time training and fine-tuning). Ignored
            when a run is resumed with ``ckpt_path`` or the module comes from a checkpoint.

    Hyper-parameters are kept as plain values, a settings group as a dict (as LightningCLI
    saves them), so that checkpoints stay readable by the safe unpickler.
    """

    #: appended to the error when ``init_weights`` does not fit (which options decide the shapes)
    weights_hint: str = ""
    #: the kind of zoo entry whose weights fit this module (:mod:`c3f_slam.models.zoo`)
    zoo_kind: str = ""
    #: state-dict key prefixes every checkpoint of this module has (they tell the kinds apart)
    checkpoint_prefixes: tuple[str, ...] = ()

    def __init__(self, optim: OptimConfig, init_weights: str | None) -> None:
        super().__init__()
        self.optim_config = optim
        self.init_weights = init_weights
        self._init_weights_done = False

    def _set_hparams(self, hp: MutableMapping) -> None:
        """Settings groups (dataclasses) saved as dicts: a checkpoint then holds no pickled classes."""
        if isinstance(hp, MutableMapping):
            hp = settings_as_dicts(hp)
        super()._set_hparams(hp)

    def configure_optimizers(self):
        cfg = self.optim_config
        opt = torch.optim.AdamW(self.parameters(), lr=cfg.lr, betas=ADAM_BETAS, weight_decay=cfg.weight_decay)
        if not cfg.milestones:
            return opt
        sched = torch.optim.lr_scheduler.MultiStepLR(opt, milestones=list(cfg.milestones), gamma=cfg.gamma)
        return {"optimizer": opt, "lr_scheduler": {"scheduler": sched, "interval": "epoch"}}

    def load_init_weights(self, path: str | Path) -> None:
        """Copy model weights from a checkpoint, a safetensors file or a zoo entry (strict);
        InputError if the file, the entry's kind or the keys do not fit."""
        hint = self.weights_hint
        if zoo.is_zoo_name(path):
            found = zoo.entry(str(path), INIT_WEIGHTS_OPTION)
            hint = f"the zoo entry's model options are in {found.folder / 'config.yaml'}"
            path = found.file_for("weights", INIT_WEIGHTS_OPTION, kind=self.zoo_kind or None)
        load_weights(self, read_checkpoint_weights(path, INIT_WEIGHTS_OPTION), path, INIT_WEIGHTS_OPTION,
                     f"this {type(self).__name__}", hint)
        self._init_weights_done = True

    def load_export_checkpoint(self, path: str | Path, option: str = "--ckpt_path") -> None:
        """Load the weights of ``path`` (a checkpoint or state dict; safe unpickler only) for an
        export and switch to evaluation mode; InputError naming ``option`` when the checkpoint
        is of another module kind or does not fit the configured architecture."""
        state = read_checkpoint_weights(path, option=option)
        kind, want = checkpoint_kind(state), type(self).__name__
        if kind is not None and kind != want:
            raise InputError(f"{option}: {path} is a {kind} checkpoint, but the config's model is {want}")
        load_weights(self, state, path, option, "the model in the config")
        self.eval()

    def setup(self, stage: str) -> None:
        # Runs before Lightning restores a ``ckpt_path``, so a resumed run keeps its own weights.
        if stage == "fit" and self.init_weights and not self._init_weights_done:
            self.load_init_weights(self.init_weights)

    def on_load_checkpoint(self, checkpoint: dict) -> None:
        self._init_weights_done = True


def checkpoint_kind(state: dict[str, torch.Tensor]) -> str | None:
    """The name of the module class (``DepthNet``, ``ContraFeat``) whose checkpoint ``state``
    is, from its key prefixes; None when none fits."""
    from c3f_models import ContraFeat, DepthNet  # the modules of this package (they subclass this one)

    for cls in (DepthNet, ContraFeat):
        if all(any(k.startswith(p) for k in state) for p in cls.checkpoint_prefixes):
            return cls.__name__
    return None


__all__ = ["INIT_WEIGHTS_OPTION", "C3FModule", "checkpoint_kind"]
