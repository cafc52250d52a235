"""The argparse parser of the project's command lines: a usage error is one line and exit status 2.

argparse prints the whole usage before its error line; :class:`OneLineParser` prints only
``error: <message> (see <prog> --help)`` (sub-commands' parsers are of the same class).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable, Mapping
from typing import NoReturn

from c3f_core.errors import InputError


class OneLineParser(argparse.ArgumentParser):
    """ArgumentParser whose usage errors are one ``error: ...`` line on stderr, exit status 2."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"error: {message} (see {self.prog} --help)\n")


def run_subcommand(commands: Mapping[str, Callable[[argparse.Namespace], int]], args: argparse.Namespace,
                   interrupted: str = "") -> int:
    """``commands[args.command](args)``; bad input (an InputError) is one ``error: ...`` line and
    exit status 2, Ctrl-C one ``error: interrupted`` line (plus ``interrupted``) and status 130."""
    try:
        return commands[args.command](args)
    except InputError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"error: interrupted{interrupted}", file=sys.stderr)
        return 130


__all__ = ["OneLineParser", "run_subcommand"]
