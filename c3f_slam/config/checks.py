"""The two range checks every settings group uses; errors name ``part.field``."""

from __future__ import annotations

from c3f_core.errors import InputError


def check(ok: bool, message: str) -> None:
    """InputError(``message``) unless ``ok``."""
    if not ok:
        raise InputError(message)


def at_least(value: float | None, low: float, name: str, none: str = "") -> None:
    """InputError unless ``value`` is None or >= ``low``; ``none`` says what None means."""
    check(value is None or value >= low,
          f"{name} must be >= {low}{f' (or None: {none})' if none else ''}, got {value}")
