"""The torch-free parts of ``python -m c3f_models``: rewriting a group field's null for the
parser (:func:`nulls_as_group_values`) and turning the parser's and constructors' errors into one
line (:func:`wrapped_input_error`, :func:`condense_parser_error`). Shared by the entry point
(:mod:`c3f_models.cli`, which imports Lightning only for Lightning's subcommands) and the
LightningCLI subclass (:mod:`c3f_models.lightning_cli`)."""

from __future__ import annotations

import json
import re
from collections.abc import Sequence

from c3f_core.errors import InputError

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


__all__ = ["condense_parser_error", "nulls_as_group_values", "wrapped_input_error"]
