"""Settings shared by both LightningModules: the optimiser group and the coercion of a group.

Each module takes its settings as a few small frozen dataclasses (``network``, ``loss``,
``optim``, ...). LightningCLI / jsonargparse read them as nested YAML
(``model.init_args.optim.lr: 1.0e-4``) or options (``--model.optim.lr 1e-4``); in Python
they are dataclass instances, or plain dicts (the form saved in checkpoints), see
:func:`as_config`. Each group validates itself in ``__post_init__``. The data modules'
groups (:mod:`datamodules.config`) work the same way.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict, dataclass, is_dataclass, replace
from typing import Any, TypeVar

from c3f_slam.errors import InputError

Config = TypeVar("Config")

ADAM_BETAS = (0.9, 0.999)


@dataclass(frozen=True)
class OptimConfig:
    """AdamW (betas 0.9, 0.999) with a MultiStepLR schedule stepped once per epoch.

    Attributes:
        lr: initial learning rate.
        weight_decay: AdamW's decoupled weight decay.
        milestones: epochs at which the learning rate is multiplied by gamma (empty: constant, no scheduler).
        gamma: factor applied at each milestone.
    """

    lr: float = 1e-4
    weight_decay: float = 1e-2
    milestones: tuple[int, ...] = (16, 24, 32)
    gamma: float = 0.5

    def __post_init__(self) -> None:
        object.__setattr__(self, "milestones", tuple(int(m) for m in self.milestones))


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


__all__ = ["ADAM_BETAS", "OptimConfig", "as_config", "settings_as_dicts"]
