"""The argparse parser of the project's command lines: a usage error is one line and exit status 2.

argparse prints the whole usage before its error line; :class:`OneLineParser` prints only
``error: <message> (see <prog> --help)`` (sub-commands' parsers are of the same class).
"""

from __future__ import annotations

import argparse
from typing import NoReturn


class OneLineParser(argparse.ArgumentParser):
    """ArgumentParser whose usage errors are one ``error: ...`` line on stderr, exit status 2."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"error: {message} (see {self.prog} --help)\n")


__all__ = ["OneLineParser"]
