"""The settings group both LightningModules share: the optimiser and its schedule.

Each module takes its settings as a few small frozen dataclasses (``network``, ``loss``,
``optim``, ...), coerced by :func:`c3f_core.settings.as_config`; each group validates itself in
``__post_init__``. The data modules' groups (:mod:`datamodules.config`) work the same way.
"""

from __future__ import annotations

from dataclasses import dataclass

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


__all__ = ["ADAM_BETAS", "OptimConfig"]
