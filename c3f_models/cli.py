"""The ``python -m c3f_models`` command line: one LightningCLI.

Model and data are chosen by class path in the config (subclass mode), e.g.::

    python -m c3f_models fit --config configs/trainer/cpu_smoke.yaml --config configs/depthnet/small.yaml

Subcommands: ``fit``, ``validate``, ``test``, ``predict`` (Lightning's), ``demo`` (the whole
pipeline, :mod:`c3f_demo`), ``zoo`` (the model zoo, :mod:`c3f_models.zoo.cli`), plus
:data:`EXTRA_SUBCOMMANDS` (methods of :class:`C3FTrainer`): ``export`` writes ONNX files::

    python -m c3f_models export --config runs/.../config.yaml --ckpt_path .../last.ckpt --output_dir exported

Model and data settings are nested groups (``--model.loss.lambda_dc 0.1``, ``--data.frames.size
[128,128]``; see :class:`c3f_models.DepthNet`, :class:`c3f_models.ContraFeat` and
:mod:`datamodules.config`). The resolved config is saved as ``config.yaml`` next to the
TensorBoard logs of each run. Bad input (:class:`c3f_slam.errors.InputError`, also when raised
by a constructor inside the parser) ends the run with a one-line ``error: ...`` and exit
status 2 instead of a traceback; so does a ``--ckpt_path`` saved with options of an older layout.
"""

from __future__ import annotations

import argparse
import json
import re
import signal
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import lightning as L
from lightning.pytorch.cli import ArgsType, LightningArgumentParser, LightningCLI

from c3f_models.checkpoints import check_checkpoint
from c3f_models.resume import run_version_of
from c3f_models.run_folder import RunFolderGuard
from c3f_models.trainer import C3FTrainer, InterruptCheckpoint
from c3f_slam.errors import InputError

# Subcommands beyond Lightning's: name -> arguments of the C3FTrainer method that the CLI
# fills itself (the instantiated model and data module); the others become options.
EXTRA_SUBCOMMANDS: dict[str, set[str]] = {"export": {"model", "datamodule"}}

SEED_DEFAULT = 42

#: a field of a settings group: ``--model.GROUP.FIELD`` or ``--data.GROUP.FIELD`` (``init_args.`` optional)
GROUP_FIELD_OPTION = re.compile(r"--((?:model|data)\.(?:init_args\.)?(?!init_args\b)\w+)\.(\w+)")
YAML_NULLS = {"null", "Null", "NULL", "~"}


def nulls_as_group_values(args: Sequence[str]) -> list[str]:
    """``args`` with each ``--data.frames.crop null`` written as ``--data.frames {"crop": null}``.

    jsonargparse (4.53) passes a group field of a class chosen by class path on as the text of its
    parsed value, so a null arrives as the string ``None`` and is refused; given as the group, the
    null stays one and the group's other fields keep their values.
    """
    out: list[str] = []
    pending: re.Match | None = None
    for arg in args:
        if pending is not None:
            group, field = pending.groups()
            out += [f"--{group}", json.dumps({field: None})] if arg in YAML_NULLS else [pending.group(0), arg]
            pending = None
            continue
        option, eq, value = arg.partition("=")
        match = GROUP_FIELD_OPTION.fullmatch(option)
        if match and not eq:
            pending = match
        elif match and value in YAML_NULLS:
            out += [f"--{match.group(1)}", json.dumps({match.group(2): None})]
        else:
            out.append(arg)
    if pending is not None:
        out.append(pending.group(0))
    return out


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


def wrapped_input_error(exc: BaseException) -> InputError | None:
    """The InputError ``exc`` is or wraps (jsonargparse re-raises a constructor's error as a ValueError)."""
    seen: set[int] = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, InputError):
            return exc
        seen.add(id(exc))
        exc = exc.__cause__ or exc.__context__
    return None


def condense_parser_error(message: str) -> str:
    """One line out of jsonargparse's multi-line validation message.

    Keeps the key the parser complained about and the innermost real reason (an option
    that is not accepted, a value of the wrong type), dropping the union-type noise.
    """
    lines = [ln.strip(" -") for ln in message.splitlines() if ln.strip()]
    if not lines:
        return "invalid arguments"
    head = lines[0]
    noise = ("Does not validate", "Subtypes:", "Errors:", "Given value", "Expected a <class 'NoneType'>")
    reasons = [ln for ln in lines[1:] if not ln.startswith(noise)]
    detail = reasons[-1] if reasons else ""
    where = [m.group(1) for ln in reasons if (m := re.search(r"class_path '([^']+)'", ln))]
    out = f"{head.rstrip(':')}: {detail}" if detail else head
    return out + (f" (in {where[-1]})" if where else "")


def run_demo_application(argv: list[str]) -> int:
    """``python -m c3f_models demo ARGS`` = ``python -m c3f_demo ARGS`` (the old spelling, kept
    for one release). The application is started by name, not imported: it sits above
    c3f_models, which never imports it. A Ctrl-C reaches the demo too (same process group),
    which stops itself cleanly; this process waits for it and returns its exit status."""
    import subprocess

    proc = subprocess.Popen([sys.executable, "-m", "c3f_demo", *argv])
    while True:
        try:
            return proc.wait()
        except KeyboardInterrupt:
            continue


def main(args: ArgsType = None, run: bool = True) -> C3FCLI | None:
    """Entry point; ``args`` lets tests drive the CLI in-process (``main(['fit', ...])``).
    ``demo`` and ``zoo`` are not LightningCLI subcommands: ``zoo`` goes to
    :mod:`c3f_models.zoo.cli`; ``demo`` runs the demo application (``python -m c3f_demo``, a
    package above this one, started by name: this spelling stays for one release)."""
    argv = sys.argv[1:] if args is None else args
    if isinstance(argv, (list, tuple)) and list(argv[:1]) == ["demo"]:
        raise SystemExit(run_demo_application(list(argv[1:])))
    if isinstance(argv, (list, tuple)) and list(argv[:1]) == ["zoo"]:
        from c3f_models.zoo.cli import main as zoo_main

        raise SystemExit(zoo_main(list(argv[1:])))
    InterruptCheckpoint.last = None
    no_exit = {"exit_on_error": False}
    parser_kwargs = {
        "prog": "python -m c3f_models",
        "description": "C3Fusion model zoo: train, evaluate and export DepthNet and ContraFeat.",
        **no_exit,
        **{name: dict(no_exit) for name in C3FCLI.subcommands()},
    }
    try:
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
    except ValueError as exc:  # InputError is one
        cause = wrapped_input_error(exc)
        if cause is None:
            raise
        print(f"error: {cause}", file=sys.stderr)
        raise SystemExit(2) from None
    except argparse.ArgumentError as exc:
        print(f"error: {condense_parser_error(str(exc))} (see --help)", file=sys.stderr)
        raise SystemExit(2) from None
    except FileNotFoundError as exc:
        print(f"error: {exc.filename or exc}: file not found", file=sys.stderr)
        raise SystemExit(2) from None
    except (SystemExit, KeyboardInterrupt) as exc:  # Lightning exits with 1 after a Ctrl-C in fit
        interrupted = InterruptCheckpoint.last
        if isinstance(exc, SystemExit) and (exc.code != 1 or interrupted is None):
            raise
        InterruptCheckpoint.last = None
        signal.signal(signal.SIGINT, signal.default_int_handler)  # Lightning ignores further Ctrl-C from here on
        print(f"error: {interrupted.message() if interrupted else 'interrupted'}", file=sys.stderr)
        raise SystemExit(130) from None


__all__ = ["C3FCLI", "EXTRA_SUBCOMMANDS", "C3FArgumentParser", "main", "nulls_as_group_values", "wrapped_input_error"]
