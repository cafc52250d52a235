"""Lightning's subcommands of ``python -m c3f_models`` (``fit``, ``validate``, ``test``,
``predict``, and :data:`EXTRA_SUBCOMMANDS`): :class:`C3FCLI`, one LightningCLI in subclass mode.

:mod:`c3f_models.cli` imports this module (and so torch and Lightning) only for these
subcommands and their ``--help``; ``zoo`` and ``demo`` start without it.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import lightning as L
from lightning.pytorch.cli import ArgsType, LightningArgumentParser, LightningCLI

from c3f_models.checkpoints import check_checkpoint
from c3f_models.cli_parsing import nulls_as_group_values, wrapped_input_error
from c3f_models.resume import run_version_of
from c3f_models.run_folder import RunFolderGuard
from c3f_models.trainer import C3FTrainer

# Subcommands beyond Lightning's: name -> arguments of the C3FTrainer method that the CLI
# fills itself (the instantiated model and data module); the others become options.
EXTRA_SUBCOMMANDS: dict[str, set[str]] = {"export": {"model", "datamodule"}}

SEED_DEFAULT = 42


class C3FArgumentParser(LightningArgumentParser):
    """Lightning's parser; a null given to a field of a settings group reaches it (:func:`nulls_as_group_values`)."""

    def parse_args(self, args: Sequence[str] | None = None, *rest, **kwargs):
        return super().parse_args(nulls_as_group_values(sys.argv[1:] if args is None else args), *rest, **kwargs)


class C3FCLI(LightningCLI):
    """LightningCLI with the project's defaults: subclass mode, seed 42, config saved."""

    @staticmethod
    def subcommands() -> dict[str, set[str]]:
        return {**LightningCLI.subcommands(), **EXTRA_SUBCOMMANDS}

    def parse_arguments(self, parser: LightningArgumentParser, args: ArgsType) -> None:
        """Lightning's, then a check of ``--ckpt_path``: LightningCLI applies the checkpoint's saved
        model class and options next, so a checkpoint with options of an older layout, of another
        model class than the config's, or (resumed ``fit``) whose options the configuration would
        change, is refused in one line before anything runs."""
        super().parse_arguments(parser, args)
        subcommand = self.config.get("subcommand")
        ckpt_path = self.config[subcommand].get("ckpt_path") if subcommand else None
        if ckpt_path and Path(ckpt_path).is_file():
            model = self.config[subcommand].get("model")
            init_args = getattr(model, "init_args", None)
            given = init_args.as_dict() if subcommand == "fit" and init_args is not None else None
            check_checkpoint(ckpt_path, getattr(model, "class_path", None), given)
            if subcommand == "fit":
                continue_run_folder(self.config.fit.trainer, ckpt_path)


    def _run_subcommand(self, subcommand: str) -> None:
        """Lightning's; a run refused for bad input (an InputError, e.g. from the model's ``setup``)
        leaves no log folder: what it created there is removed (:class:`RunFolderGuard`)."""
        guard = RunFolderGuard.before(self.trainer.log_dir)
        try:
            super()._run_subcommand(subcommand)
        except Exception as exc:
            if guard is not None and wrapped_input_error(exc) is not None:
                guard.roll_back()
            raise


def continue_run_folder(trainer_config: Any, ckpt_path: str) -> None:
    """A resumed ``fit`` logs into the TensorBoard run folder its checkpoint is in (same version,
    step numbers continuing): the configured TensorBoardLogger's ``version``, unless given, is
    set to that folder's (:func:`c3f_models.resume.run_version_of`)."""
    logger = trainer_config.get("logger")
    init_args = getattr(logger, "init_args", None)
    if not str(getattr(logger, "class_path", "")).endswith("TensorBoardLogger") or init_args is None:
        return
    if init_args.get("version") is None:
        version = run_version_of(ckpt_path, init_args.get("save_dir"), init_args.get("name", "lightning_logs"))
        if version is not None:
            init_args.version = version


def run_cli(args: ArgsType = None, run: bool = True) -> C3FCLI:
    """:class:`C3FCLI` on ``args`` (None: ``sys.argv``): parse, and with ``run`` run the
    subcommand. Errors are the parser's and the run's own (:func:`c3f_models.cli.main` makes
    them one line)."""
    no_exit = {"exit_on_error": False}
    parser_kwargs = {
        "prog": "python -m c3f_models",
        "description": "C3Fusion model zoo: train, evaluate and export DepthNet and ContraFeat.",
        **no_exit,
        **{name: dict(no_exit) for name in C3FCLI.subcommands()},
    }
    return C3FCLI(
        L.LightningModule,
        L.LightningDataModule,
        trainer_class=C3FTrainer,
        parser_class=C3FArgumentParser,
        subclass_mode_model=True,
        subclass_mode_data=True,
        seed_everything_default=SEED_DEFAULT,
        save_config_kwargs={"overwrite": True},
        parser_kwargs=parser_kwargs,
        args=args,
        run=run,
    )


__all__ = ["C3FCLI", "EXTRA_SUBCOMMANDS", "SEED_DEFAULT", "C3FArgumentParser", "continue_run_folder", "run_cli"]
