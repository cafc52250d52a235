"""How a run gets its settings tree: a preset, a config file, ``--set`` overrides; and the
tree written back as commented YAML (``--print-config``).

Order (later wins): the preset (``--preset``, else the file's ``preset``, else colon), then the
file's values (YAML or JSON, complete or partial, in the form of :meth:`SlamConfig.as_dict`; a
run's ``summary.json`` as is: its ``config`` is the tree that run used), then each ``--set
part.field=value`` in command-line order (dotted paths, the simulator's dialect; values as on
a command line: ``0.8``, ``none``, ``true``, ``0.002,0.001``, or ``{...}`` YAML for a whole
group). Every value is converted to its field's type and checked by its group: a bad one is
one InputError naming ``part.field`` (and the file).
"""

from __future__ import annotations

import json
import re
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, fields, is_dataclass
from pathlib import Path
from typing import Any

from c3f_core.errors import InputError
from c3f_core.settings import field_docs, field_types, tree_from_mapping, type_name
from c3f_slam.config.presets import preset
from c3f_slam.config.tree import SlamConfig


@dataclass(frozen=True)
class ConfigFile:
    """A config file's settings (nested mapping) and, for a run's summary.json, that summary."""

    path: Path
    settings: dict[str, Any]
    summary: dict[str, Any] | None = None  #: the whole summary.json a replayed run wrote


def read_config_file(path: str | Path) -> ConfigFile:
    """The settings in ``path`` (YAML or JSON; a run's summary.json: its ``config``).
    InputError naming the file when it is missing, unreadable or not a mapping."""
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
    if isinstance(data.get("config"), Mapping) and "status" in data:  # a run's summary.json
        return ConfigFile(path, dict(data["config"]), dict(data))
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


def resolve_config(preset_name: str | None = None, config: ConfigFile | None = None,
                   sets: Iterable[str] = ()) -> SlamConfig:
    """The settings tree of a run: the preset, the config file's values, then the ``--set``
    items in order (see the module notes). InputError for a preset that contradicts the
    file's, an unknown setting or a bad value (naming the file where it came from)."""
    settings = dict(config.settings) if config else {}
    file_preset = settings.get("preset")
    if preset_name and file_preset and preset_name != file_preset:
        raise InputError(f"--preset {preset_name} contradicts preset: {file_preset} in {config.path} "
                         f"(drop one; change single settings with --set)")
    changes: dict[str, Any] = {}
    for item in sets:
        changes = merge(changes, _nest(*parse_set(item)))
    name = changes.get("preset") or preset_name or file_preset or "colon"
    base = preset(str(name))
    if config:
        try:
            base = tree_from_mapping(base, settings)
        except InputError as exc:
            raise InputError(f"--config {config.path}: {exc}") from None
    try:
        return tree_from_mapping(base, changes)
    except InputError as exc:
        raise InputError(f"--set: {exc}") from None


def _summary_line(doc: str) -> str:
    """The first paragraph of a docstring on one line, Sphinx roles reduced to their names."""
    first = " ".join(doc.strip().split("\n\n")[0].split())
    return re.sub(r":\w+:`~?([^`]+)`", r"\1", first)


def config_yaml(cfg: SlamConfig) -> str:
    """The tree as YAML that :func:`read_config_file` reads back, each setting commented with
    its type and meaning (from the dataclasses' ``#:`` comments)."""
    import yaml

    lines = [
        "# C3Fusion SLAM settings: python -m c3f_slam run SEQ --out OUT --config THIS_FILE",
        "# (or change single settings: --set part.field=value). Lengths in metres, angles in degrees.",
    ]

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

    emit(cfg, "")
    return "\n".join(lines) + "\n"


__all__ = ["ConfigFile", "config_yaml", "merge", "parse_set", "read_config_file", "resolve_config"]
