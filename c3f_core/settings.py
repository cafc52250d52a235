"""Helpers for settings groups: small frozen dataclasses that validate themselves.

A leaf module (it imports only :mod:`c3f_core.errors`), so every layer can use it: the runtime
(:mod:`c3f_slam.config`), the simulator, the data modules (:mod:`datamodules.config`) and the
LightningModules (:mod:`c3f_models.config`). In a LightningCLI config the groups are nested YAML
(``model.init_args.optim.lr: 1.0e-4``) or options (``--model.optim.lr 1e-4``); in Python they are
dataclass instances, or plain dicts (the form saved in checkpoints), see :func:`as_config`.

A tree of settings dataclasses (a dataclass whose fields may be dataclasses) is read and changed
by dotted paths, the dialect of every ``--set part.field=value`` option of the project:

- :func:`convert_value`: a command-line string (or a value read from YAML / JSON) as a field's
  type (``int``, ``float``, ``bool``, ``str``, ``X | None``, ``tuple[X, ...]``, ``tuple[X, Y]``,
  a nested group);
- :func:`set_path`: a copy of a frozen tree with one dotted field replaced (the groups validate
  the result themselves);
- :func:`tree_from_mapping` / :func:`tree_as_mapping`: a tree from nested mappings (a config
  file) and back, unknown keys rejected;
- :func:`field_docs`: the ``#:`` comments of a dataclass's fields (help texts from the one place
  that defines defaults and ranges).
"""

from __future__ import annotations

import inspect
import re
import types
import typing
from collections.abc import Mapping
from dataclasses import asdict, fields, is_dataclass, replace
from functools import cache
from typing import Any, TypeVar

from c3f_core.errors import InputError

Config = TypeVar("Config")


def as_config(value: Config | Mapping[str, Any], default: Config, option: str) -> Config:
    """``value`` as a settings group of ``default``'s class: itself, or ``default`` with the
    fields of a mapping replaced (as the CLI fills a partly given group).

    The mapping form is how groups come back from a checkpoint's hyper-parameters
    (``load_from_checkpoint``) and what tests and scripts may pass. An unknown field is an
    InputError naming ``option``.
    """
    cls = type(default)
    if isinstance(value, cls):
        return value
    if isinstance(value, Mapping):
        try:
            return replace(default, **value)
        except TypeError as exc:
            raise InputError(f"{option}: {exc}") from None
    raise InputError(f"{option}: expected {cls.__name__} settings (a mapping), got {type(value).__name__}")


def settings_as_dicts(hparams: Mapping[str, Any]) -> dict[str, Any]:
    """``hparams`` with each settings group (a dataclass) as a dict of its fields, the form
    LightningCLI saves: a checkpoint then holds no pickled classes (the safe unpickler reads it)."""
    return {k: asdict(v) if is_dataclass(v) else v for k, v in hparams.items()}


_TRUE, _FALSE, _NONE = ("1", "true", "yes", "on"), ("0", "false", "no", "off"), ("none", "null", "~", "")


@cache
def field_types(cls: type) -> dict[str, Any]:
    """The resolved type hints of dataclass ``cls``'s fields (string annotations evaluated)."""
    return typing.get_type_hints(cls)


def _optional_inner(tp: Any) -> Any | None:
    """``X`` of ``X | None`` (None when ``tp`` is not optional)."""
    if typing.get_origin(tp) in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        if len(args) == 1 and len(typing.get_args(tp)) == 2:
            return args[0]
    return None


def type_name(tp: Any) -> str:
    """A short readable name of a field type (``int | None``, ``tuple[float, ...]``)."""
    inner = _optional_inner(tp)
    if inner is not None:
        return f"{type_name(inner)} | None"
    if typing.get_origin(tp) is tuple:
        return f"tuple[{', '.join('...' if a is Ellipsis else type_name(a) for a in typing.get_args(tp))}]"
    return getattr(tp, "__name__", str(tp))


def convert_value(value: Any, tp: Any, name: str) -> Any:
    """``value`` as type ``tp``: a command-line string (``"0.8"``, ``"none"``, ``"true"``,
    ``"1,2,3"``) or a value read from YAML / JSON. InputError naming ``name`` otherwise; an
    integer field takes a float only when it is a whole number, a bool field no number but 0/1."""
    inner = _optional_inner(tp)
    if inner is not None:
        if value is None or (isinstance(value, str) and value.strip().lower() in _NONE):
            return None
        return convert_value(value, inner, name)
    try:
        return _convert_plain(value, tp, name)
    except (TypeError, ValueError):
        raise InputError(f"{name}: cannot use {value!r} (expected {type_name(tp)})") from None


def _convert_plain(value: Any, tp: Any, name: str) -> Any:
    if is_dataclass(tp):
        if not isinstance(value, Mapping):
            raise TypeError(value)
        return tree_from_mapping(tp(), value, name)
    if typing.get_origin(tp) is tuple:
        args = typing.get_args(tp)
        if isinstance(value, str):
            value = _split_tuple(value, typing.get_origin(args[0]) is tuple)
        if not isinstance(value, (list, tuple)):
            raise TypeError(value)
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(convert_value(v, args[0], name) for v in value)
        if len(value) != len(args):  # fixed length, e.g. tuple[str, int]
            raise ValueError(value)
        return tuple(convert_value(v.strip() if isinstance(v, str) else v, a, name)
                     for v, a in zip(value, args, strict=True))
    if isinstance(value, str) and tp is not str:
        value = value.strip()
    if tp is bool:
        low = str(value).lower()
        if isinstance(value, bool) or low in _TRUE + _FALSE:
            return value if isinstance(value, bool) else low in _TRUE
        raise ValueError(value)
    if tp is int:
        if isinstance(value, bool) or (isinstance(value, float) and not value.is_integer()):
            raise ValueError(value)
        if isinstance(value, str):
            as_float = float(value)
            if not as_float.is_integer():
                raise ValueError(value)
            return int(value) if value.lstrip("+-").isdigit() else int(as_float)
        return int(value)
    if tp is float:
        if isinstance(value, bool):
            raise ValueError(value)
        return float(value)
    if tp is str:
        if isinstance(value, (Mapping, list, tuple)) or value is None:
            raise TypeError(value)
        return str(value)
    raise TypeError(f"{name}: unsupported field type {tp!r}")


def _split_tuple(text: str, nested: bool) -> list[str]:
    """A command-line tuple's items: ``"1,2,3"`` / ``"[1, 2]"``; ``nested``: its bracketed groups,
    ``"[[a,1],[b,2]]"`` -> ``["a,1", "b,2"]``."""
    text = text.strip()
    if not nested:
        return [v for v in text.strip("[]()").split(",") if v.strip()]
    inner = text[1:-1] if text[:2] in ("[[", "[(", "((", "([") else text
    groups, rest = _GROUP.findall(inner), _GROUP.sub("", inner).strip(" ,")
    if rest and groups:
        raise ValueError(text)
    if not rest and not "".join(groups).strip():  # "", "[]"
        return []
    return groups or [inner]  # "a,1": one item


_GROUP = re.compile(r"[\[(]([^\[\]()]*)[\])]")


def _field_type(obj: Any, key: str, where: str) -> Any:
    """The type of field ``key`` of dataclass instance ``obj``; InputError naming ``where`` if none."""
    hints = field_types(type(obj))
    if key not in hints or key not in {f.name for f in fields(obj)}:
        known = ", ".join(f.name for f in fields(obj))
        raise InputError(f"unknown setting {where!r} (known here: {known})")
    return hints[key]


def set_path(tree: Any, path: str, value: Any, root: str = "") -> Any:
    """A copy of the dataclass ``tree`` with the field at dotted ``path`` set to ``value``
    (converted by :func:`convert_value`; a group takes a mapping of its fields). The copies are
    made with :func:`dataclasses.replace`, so each group checks its new values itself."""
    head, _, rest = path.partition(".")
    where = f"{root}{head}"
    tp = _field_type(tree, head, where)
    current = getattr(tree, head)
    if rest:
        if not is_dataclass(current):
            raise InputError(f"unknown setting {root + path!r}: {where} is a {type_name(tp)}, not a group")
        new = set_path(current, rest, value, f"{where}.")
    elif is_dataclass(current) and isinstance(value, Mapping):
        new = tree_from_mapping(current, value, where)
    else:
        new = convert_value(value, tp, where)
    return replace(tree, **{head: new})


def tree_from_mapping(base: Any, mapping: Mapping[str, Any], where: str = "") -> Any:
    """``base`` (a dataclass tree) with the fields of the nested ``mapping`` set, in order;
    InputError for an unknown key (naming its dotted path under ``where``)."""
    if not isinstance(mapping, Mapping):
        raise InputError(f"{where or 'settings'}: expected a mapping of settings, got {type(mapping).__name__}")
    prefix = f"{where}." if where else ""
    changes: dict[str, Any] = {}
    for key, value in mapping.items():
        tp = _field_type(base, str(key), prefix + str(key))
        current = getattr(base, key)
        if is_dataclass(current) and isinstance(value, Mapping):
            changes[key] = tree_from_mapping(current, value, prefix + key)
        else:
            changes[key] = convert_value(value, tp, prefix + key)
    return replace(base, **changes) if changes else base


def tree_as_mapping(tree: Any) -> dict[str, Any]:
    """The dataclass ``tree`` as nested plain dicts (tuples as lists: the YAML / JSON form)."""
    def plain(v: Any) -> Any:
        if isinstance(v, dict):
            return {k: plain(x) for k, x in v.items()}
        if isinstance(v, (list, tuple)):
            return [plain(x) for x in v]
        return v

    return plain(asdict(tree))


_DOC = re.compile(r"^\s*(\w+)\s*:[^#]*?(?:#:\s*(.*))?$")


@cache
def field_docs(cls: type) -> dict[str, str]:
    """The ``#:`` comment of each field of dataclass ``cls`` (on the field's line, or the lines
    just above it), as Sphinx reads them; fields without one are left out."""
    try:
        lines = inspect.getsource(cls).splitlines()
    except (OSError, TypeError):  # pragma: no cover - no source (frozen app)
        return {}
    names = {f.name for f in fields(cls)}
    docs: dict[str, str] = {}
    above: list[str] = []
    for line in lines[1:]:
        stripped = line.strip()
        if stripped.startswith("#:"):
            above.append(stripped[2:].strip())
            continue
        m = _DOC.match(line)
        if m and m.group(1) in names and m.group(1) not in docs:
            text = " ".join(above + ([m.group(2).strip()] if m.group(2) else []))
            if text:
                docs[m.group(1)] = text
        above = []
    return docs


__all__ = ["as_config", "convert_value", "field_docs", "field_types", "set_path", "settings_as_dicts",
           "tree_as_mapping", "tree_from_mapping", "type_name"]
