"""Every command's settings options: ``--preset``, ``--config FILE``, ``--set part.field=value``,
``--print-config``, for any tree of frozen settings dataclasses.

A command names its tree's presets (complete instances; one, ``default``, when it has none) and
gets the same dialect everywhere (the runtime, the simulator, the demo, the benchmark
protocols). Order (later wins): the preset (``--preset``, else the file's ``preset``, else the
command's default), then the file's values (YAML or JSON, complete or partial, in the form
``--print-config`` writes; or the record an earlier run of the command wrote, whose settings sit
under one key, e.g. a run's ``summary.json`` ``config``), then each ``--set`` in command-line
order (values as on a command line: ``0.8``, ``none``, ``true``, ``0.002,0.001``, or ``{...}``
YAML for a whole group). Every value is converted to its field's type and checked by its group;
a bad one is one InputError naming ``part.field`` (and the file). Help texts and the YAML's
comments come from the dataclasses' ``#:`` comments: defaults live only there.
"""

from __future__ import annotations

import argparse
import json
import re
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, fields, is_dataclass
from pathlib import Path
from typing import Any, Generic, TypeVar

from c3f_core.errors import InputError
from c3f_core.settings import field_docs, field_types, tree_from_mapping, type_name

Tree = TypeVar("Tree")


@dataclass(frozen=True)
class ConfigFile:
    """A config file's settings (nested mapping) and, for an earlier run's record, that record."""

    path: Path
    settings: dict[str, Any]
    record: dict[str, Any] | None = None  #: the whole file when the settings came from under ``record_key``


def read_config_file(path: str | Path, record_key: str | None = None) -> ConfigFile:
    """The settings in ``path`` (YAML or JSON). A mapping whose ``record_key`` entry is a mapping is
    an earlier run's record: its settings are that entry. InputError naming the file when it is
    missing, unreadable or not a mapping."""
    import yaml

    path = Path(path)
    if not path.is_file():
        raise InputError(f"--config: {path} not found")
    try:
        text = path.read_text()
        data = json.loads(text) if path.suffix.lower() == ".json" else yaml.safe_load(text)
    except (OSError, UnicodeDecodeError, ValueError, yaml.YAMLError) as exc:
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise InputError(f"--config: {path} is not valid {'JSON' if path.suffix == '.json' else 'YAML'} "
                         f"({first})") from None
    if data is None:
        data = {}
    if not isinstance(data, Mapping):
        raise InputError(f"--config: {path} must hold a mapping of settings, got {type(data).__name__}")
    if record_key and isinstance(data.get(record_key), Mapping):
        return ConfigFile(path, dict(data[record_key]), dict(data))
    return ConfigFile(path, dict(data))


def parse_set(item: str) -> tuple[str, Any]:
    """``"part.field=value"`` -> (``"part.field"``, ``"value"``); a value starting with ``{`` is
    read as YAML (a whole group). InputError for anything else."""
    key, sep, value = item.partition("=")
    key = key.strip()
    if not sep or not key or any(not k.isidentifier() for k in key.split(".")):
        raise InputError(f"--set: expected part.field=VALUE, got {item!r}")
    value = value.strip()
    if value.startswith("{"):
        import yaml

        try:
            return key, yaml.safe_load(value)
        except yaml.YAMLError:
            raise InputError(f"--set {key}: {value!r} is not a YAML mapping") from None
    return key, value


def _nest(path: str, value: Any) -> dict[str, Any]:
    head, _, rest = path.partition(".")
    return {head: _nest(rest, value) if rest else value}


def merge(base: Mapping[str, Any], changes: Mapping[str, Any]) -> dict[str, Any]:
    """``base`` with ``changes`` merged in, nested mappings merged key by key."""
    out = dict(base)
    for key, value in changes.items():
        if isinstance(value, Mapping) and isinstance(out.get(key), Mapping):
            out[key] = merge(out[key], value)
        else:
            out[key] = value
    return out


@dataclass(frozen=True)
class SettingsSpec(Generic[Tree]):
    """What a command's settings are: its presets (name -> a function giving the complete tree),
    the default preset, the record key of the files its runs write, and the command line that
    reads a settings file (the first line of ``--print-config``)."""

    presets: Mapping[str, Callable[[], Tree]]
    default: str = "default"
    record_key: str | None = None  #: the key under which the command's records keep their settings
    usage: str = ""  #: e.g. ``python -m c3f_slam run SEQ --out OUT --config THIS_FILE``

    def tree(self, name: str) -> Tree:
        """Preset ``name``; InputError naming the known ones."""
        if name not in self.presets:
            raise InputError(f"--preset: unknown preset {name!r} (known: {', '.join(self.presets)})")
        return self.presets[name]()

    def resolve(self, preset_name: str | None = None, config: ConfigFile | None = None,
                sets: Iterable[str] = ()) -> Tree:
        """The settings tree: the preset, the config file's values, then the ``--set`` items in
        order (see the module notes). With several presets, a ``preset`` key (in the file or a
        ``--set``) picks the preset (the tree records it in a field of that name); with one, a field
        ``preset`` is an ordinary setting. InputError for a preset that contradicts the file's, an
        unknown setting or a bad value (naming the file where it came from)."""
        settings = dict(config.settings) if config else {}
        chooses = len(self.presets) > 1  # else a field ``preset`` is an ordinary setting
        file_preset = settings.get("preset") if chooses else None
        if preset_name and file_preset and preset_name != file_preset:
            raise InputError(f"--preset {preset_name} contradicts preset: {file_preset} in {config.path} "
                             f"(drop one; change single settings with --set)")
        changes: dict[str, Any] = {}
        for item in sets:
            changes = merge(changes, _nest(*parse_set(item)))
        base = self.tree(str((changes.get("preset") if chooses else None) or preset_name or file_preset
                             or self.default))
        if config:
            try:
                base = tree_from_mapping(base, settings)
            except InputError as exc:
                raise InputError(f"--config {config.path}: {exc}") from None
        try:
            return tree_from_mapping(base, changes)
        except InputError as exc:
            raise InputError(f"--set: {exc}") from None

    def from_args(self, args: argparse.Namespace) -> Tree:
        """The tree the options of :func:`add_settings_options` give."""
        config = read_config_file(args.config, self.record_key) if getattr(args, "config", None) else None
        return self.resolve(getattr(args, "preset", None), config, getattr(args, "set", None) or ())

    def yaml(self, tree: Tree) -> str:
        """``tree`` as YAML :meth:`resolve` reads back, each setting commented (see :func:`settings_yaml`)."""
        return settings_yaml(tree, self.usage)


def _summary_line(doc: str) -> str:
    """The first paragraph of a docstring on one line, Sphinx roles reduced to their names."""
    first = " ".join(doc.strip().split("\n\n")[0].split())
    return re.sub(r":\w+:`~?([^`]+)`", r"\1", first)


def settings_yaml(tree: Any, usage: str = "") -> str:
    """The dataclass ``tree`` as YAML, each setting commented with its type and meaning (from the
    dataclasses' ``#:`` comments), under a header naming the command that reads it."""
    import yaml

    lines = []
    if usage:
        lines += [f"# C3Fusion settings: {usage}",
                  "# (or change single settings: --set part.field=value). Lengths in metres, angles in degrees."]

    def emit(obj: Any, indent: str) -> None:
        docs, types = field_docs(type(obj)), field_types(type(obj))
        for f in fields(obj):
            value, note = getattr(obj, f.name), docs.get(f.name, "")
            if is_dataclass(value):
                doc = _summary_line(type(value).__doc__ or "")
                lines.append(f"{indent}{f.name}:  # {doc}")
                emit(value, indent + "  ")
                continue
            text = yaml.safe_dump(list(value) if isinstance(value, tuple) else value, default_flow_style=True,
                                  width=1000).strip()
            text = text.removesuffix("\n...").strip()
            lines.append(f"{indent}{f.name}: {text}  # {type_name(types[f.name])}" + (f": {note}" if note else ""))

    emit(tree, "")
    return "\n".join(lines) + "\n"


class SetItems(argparse.Action):
    """``--set``: append a ``part.field=value`` item to ``namespace.set`` (checked when the tree is built)."""

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace, values: Any,
                 option_string: str | None = None) -> None:
        namespace.set = [*(getattr(namespace, "set", None) or []), values]


def add_settings_options(parser: argparse.ArgumentParser, spec: SettingsSpec[Any], example: str = "",
                         replay: str = "") -> argparse._ArgumentGroup:
    """``--preset`` (when ``spec`` has more than one), ``--config``, ``--set``, ``--print-config``
    on ``parser``; ``example`` is a ``--set`` item for the help, ``replay`` names the file an
    earlier run wrote that ``--config`` replays. Returns the group (a command may add to it)."""
    g = parser.add_argument_group("settings (every setting, its default and meaning: --print-config)")
    if len(spec.presets) > 1:
        g.add_argument("--preset", choices=list(spec.presets),
                       help=f"the settings the others start from (default: {spec.default})")
    g.add_argument("--config", metavar="FILE",
                   help="settings file, YAML or JSON (complete or partial, as --print-config writes it)"
                        + (f", or {replay} as is: replays that run's settings" if replay else ""))
    g.add_argument("--set", action=SetItems, default=[], metavar="PART.FIELD=VALUE",
                   help="change one setting" + (f", e.g. --set {example}" if example else "")
                        + " (after --config; repeatable, the last wins)")
    g.add_argument("--print-config", action="store_true",
                   help="print the settings this command line gives (YAML, each with its type and meaning) and exit")
    return g


__all__ = ["ConfigFile", "SetItems", "SettingsSpec", "add_settings_options", "merge", "parse_set",
           "read_config_file", "settings_yaml"]
