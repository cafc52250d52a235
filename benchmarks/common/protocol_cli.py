"""The command line of every protocol: its settings as one frozen dataclass, read as every command
of the project reads settings (:mod:`c3f_core.settings_cli`).

A protocol declares its measurement settings (frames, sizes, seeds, paces, repeats, model names,
thresholds) as one frozen dataclass, each field with its default and a ``#:`` comment giving its
meaning and units; :class:`ProtocolCli` gives it ``--config FILE`` (YAML or JSON, or the
protocol's results JSON as is: ``--config benchmarks/results/NAME.json`` replays that run's
settings, kept under ``settings``), ``--set field=value`` (repeatable), ``--print-config``
(commented YAML, exit 0, nothing run) and one-line usage errors (exit status 2).

``--work`` (the folder for sequences and runs, default ``runs/bench/NAME``) and ``--report`` (the
Markdown report, default ``benchmarks/results/NAME.md``) stay plain options: they say where
things go, not what is measured, so a replayed run never writes over another's folders. Each
protocol declares them itself (``ap.add_argument("--report", ..., default=RESULTS / "NAME.md")``:
tests/test_results_layout.py reads the default report from the source), as it does the paths of
its inputs (a checkout to compare with, a recording). :meth:`Report.publish` records the settings
tree under ``settings`` and those plain options under ``options``.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Iterable
from dataclasses import asdict, dataclass, is_dataclass
from typing import Any, Generic, TypeVar

from c3f_core.cli_parser import OneLineParser
from c3f_core.errors import InputError
from c3f_core.settings_cli import SettingsSpec, add_settings_options

S = TypeVar("S")

RECORD_KEY = "settings"  #: the key of a protocol's results JSON that holds its settings tree
WORK_HELP = "folder for the protocol's sequences and runs (default: %(default)s)"
REPORT_HELP = "the Markdown report, and the same run as JSON beside it (.json) (default: %(default)s)"
_SETTINGS_DESTS = ("config", "set", "print_config")


def check_choices(name: str, values: Any, allowed: Iterable[str]) -> None:
    """InputError naming setting ``name`` unless ``values`` (one value or a tuple) are all in ``allowed``."""
    allowed = tuple(allowed)
    for v in values if isinstance(values, tuple) else (values,):
        if v not in allowed:
            raise InputError(f"{name}: unknown value {v!r} (known: {', '.join(map(str, allowed))})")


def check_not_empty(settings: Any, *names: str) -> None:
    """InputError naming the first of the tuple settings ``names`` of ``settings`` that is empty."""
    for name in names:
        if not getattr(settings, name):
            raise InputError(f"{name}: give at least one value")


@dataclass(frozen=True)
class ProtocolCli(Generic[S]):
    """The settings command line of the protocol ``name`` (its module's stem), whose settings are
    the dataclass ``settings`` (defaults written only there); ``example`` is a ``--set`` item shown
    in the help."""

    name: str
    settings: type[S]
    doc: str = ""
    example: str = ""

    @property
    def prog(self) -> str:
        """How the protocol runs: ``python -m benchmarks.protocols.NAME``."""
        return f"python -m benchmarks.protocols.{self.name}"

    @property
    def spec(self) -> SettingsSpec[S]:
        """The protocol's :class:`SettingsSpec`: one preset (the dataclass's defaults), replay key ``settings``."""
        return SettingsSpec(presets={"default": self.settings}, record_key=RECORD_KEY,
                            usage=f"{self.prog} --config THIS_FILE")

    def parser(self) -> OneLineParser:
        """A parser with the settings options; the protocol adds ``--work``, ``--report`` and its inputs."""
        first = " ".join((self.doc or "").strip().split("\n\n")[0].split())
        ap = OneLineParser(prog=self.prog, description=first)
        add_settings_options(ap, self.spec, self.example, replay=f"benchmarks/results/{self.name}.json")
        return ap

    def parse(self, ap: argparse.ArgumentParser, argv: list[str] | None = None) -> tuple[argparse.Namespace, S]:
        """The plain options and the settings tree of ``argv`` (default: ``sys.argv[1:]``). With
        ``--print-config`` prints the tree as commented YAML and exits 0; bad settings are one
        ``error: ...`` line and exit status 2. The returned options hold no settings options."""
        args = ap.parse_args(argv)
        try:
            tree = self.spec.from_args(args)
        except InputError as exc:
            ap.error(str(exc))
        if args.print_config:
            sys.stdout.write(self.spec.yaml(tree))
            raise SystemExit(0)
        for dest in _SETTINGS_DESTS:
            if hasattr(args, dest):
                delattr(args, dest)
        assert is_dataclass(tree)
        return args, tree

    @staticmethod
    def flat(args: argparse.Namespace, settings: Any) -> argparse.Namespace:
        """One namespace: the plain options ``args``, each setting as an attribute (tuples as lists, as
        argparse gave them) and ``settings``, the tree (for the protocols whose functions take one namespace)."""
        values = {k: list(v) if isinstance(v, tuple) else v for k, v in asdict(settings).items()}
        return argparse.Namespace(**vars(args), **values, settings=settings)


__all__ = ["RECORD_KEY", "REPORT_HELP", "WORK_HELP", "ProtocolCli", "check_choices", "check_not_empty"]
