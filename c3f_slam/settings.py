"""Helpers for settings groups: small frozen dataclasses that validate themselves.

A leaf module (it imports only :mod:`c3f_slam.errors`), so every layer can use it: the runtime,
the data modules (:mod:`datamodules.config`) and the LightningModules (:mod:`c3f_models.config`).
In a LightningCLI config the groups are nested YAML (``model.init_args.optim.lr: 1.0e-4``) or
options (``--model.optim.lr 1e-4``); in Python they are dataclass instances, or plain dicts (the
form saved in checkpoints), see :func:`as_config`.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict, is_dataclass, replace
from typing import Any, TypeVar

from c3f_slam.errors import InputError

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


__all__ = ["as_config", "settings_as_dicts"]
