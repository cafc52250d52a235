"""How a run gets its settings tree: the runtime's :class:`~c3f_core.settings_cli.SettingsSpec`.

Presets ``colon`` (default) and ``room``; a config file may be a run's ``summary.json`` as is
(its ``config`` is the tree that run used); the order of preset, file and ``--set`` and the
dialect of values are those of every command (:mod:`c3f_core.settings_cli`).
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

from c3f_core.settings_cli import ConfigFile, SettingsSpec
from c3f_core.settings_cli import read_config_file as _read
from c3f_slam.config.presets import PRESETS
from c3f_slam.config.tree import SlamConfig

#: the runtime's settings: its presets, the summary.json key that replays a run, the command
SLAM_SETTINGS: SettingsSpec[SlamConfig] = SettingsSpec(
    presets={name: (lambda tree=tree: tree) for name, tree in PRESETS.items()}, default="colon",
    record_key="config", usage="python -m c3f_slam run SEQ --out OUT --config THIS_FILE")


def read_config_file(path: str | Path) -> ConfigFile:
    """The settings in ``path`` (YAML or JSON; a run's summary.json: its ``config``)."""
    return _read(path, SLAM_SETTINGS.record_key)


def resolve_config(preset_name: str | None = None, config: ConfigFile | None = None,
                   sets: Iterable[str] = ()) -> SlamConfig:
    """The settings tree of a run (see :meth:`SettingsSpec.resolve`)."""
    return SLAM_SETTINGS.resolve(preset_name, config, sets)


def config_yaml(cfg: SlamConfig) -> str:
    """The tree as commented YAML that :func:`read_config_file` reads back."""
    return SLAM_SETTINGS.yaml(cfg)


__all__ = ["SLAM_SETTINGS", "config_yaml", "read_config_file", "resolve_config"]
