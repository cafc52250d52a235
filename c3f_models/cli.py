"""The ``python -m c3f_models`` command line: one LightningCLI (:mod:`c3f_models.lightning_cli`),
plus ``zoo`` and ``demo``, which start without importing torch or Lightning.

Model and data are chosen by class path in the config (subclass mode), e.g.::

    python -m c3f_models fit --config configs/trainer/cpu_smoke.yaml --config configs/depthnet/small.yaml

Subcommands: ``fit``, ``validate``, ``test``, ``predict`` (Lightning's), ``demo`` (the whole
pipeline, :mod:`c3f_demo`), ``zoo`` (the model zoo, :mod:`c3f_models.zoo.cli`), plus
:data:`~c3f_models.lightning_cli.EXTRA_SUBCOMMANDS` (methods of
:class:`~c3f_models.trainer.C3FTrainer`): ``export`` writes ONNX files::

    python -m c3f_models export --config runs/.../config.yaml --ckpt_path .../last.ckpt --output_dir exported

Model and data settings are nested groups (``--model.loss.lambda_dc 0.1``, ``--data.frames.size
[128,128]``; see :class:`c3f_models.DepthNet`, :class:`c3f_models.ContraFeat` and
:mod:`datamodules.config`). The resolved config is saved as ``config.yaml`` next to the
TensorBoard logs of each run. Bad input (:class:`c3f_core.errors.InputError`, also when raised
by a constructor inside the parser) ends the run with a one-line ``error: ...`` and exit
status 2 instead of a traceback; so does a ``--ckpt_path`` saved with options of an older layout.
"""

from __future__ import annotations

import argparse
import importlib
import signal
import sys
from typing import TYPE_CHECKING, Any

from c3f_models.cli_parsing import condense_parser_error, nulls_as_group_values, wrapped_input_error

if TYPE_CHECKING:
    from lightning.pytorch.cli import ArgsType

    from c3f_models.lightning_cli import C3FCLI, EXTRA_SUBCOMMANDS, C3FArgumentParser

#: names of :mod:`c3f_models.lightning_cli` that this module gives too (imported on first access,
#: so that ``zoo`` and ``demo`` start without torch and Lightning)
LIGHTNING_NAMES = ("C3FCLI", "C3FArgumentParser", "EXTRA_SUBCOMMANDS", "SEED_DEFAULT", "continue_run_folder")


def __getattr__(name: str) -> Any:
    if name not in LIGHTNING_NAMES:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module("c3f_models.lightning_cli"), name)


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
    package above this one, started by name: this spelling stays for one release). Neither
    imports torch or Lightning; the other subcommands run :func:`c3f_models.lightning_cli.run_cli`."""
    argv = sys.argv[1:] if args is None else args
    if isinstance(argv, (list, tuple)) and list(argv[:1]) == ["demo"]:
        raise SystemExit(run_demo_application(list(argv[1:])))
    if isinstance(argv, (list, tuple)) and list(argv[:1]) == ["zoo"]:
        from c3f_models.zoo.cli import main as zoo_main

        raise SystemExit(zoo_main(list(argv[1:])))
    from c3f_models.lightning_cli import run_cli
    from c3f_models.trainer import InterruptCheckpoint

    InterruptCheckpoint.last = None
    try:
        return run_cli(args, run)
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


__all__ = ["C3FCLI", "EXTRA_SUBCOMMANDS", "C3FArgumentParser", "condense_parser_error", "main", "nulls_as_group_values",
           "wrapped_input_error"]
