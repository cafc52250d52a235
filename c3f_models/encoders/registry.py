"""Choosing an encoder by name: :data:`ENCODERS`, or the class path of any :class:`Encoder` subclass.

A network config names its encoder (``encoder: mobilenet_v3_small``) and may give that encoder's
own settings as a mapping (``encoder_options: {width_mult: 0.75}``). The ResNet's settings keep
the flat options they always had (``encoder_layers``, ``encoder_width``, ``dcn``: saved configs and
checkpoints load unchanged); they are refused beside another encoder, so none is silently ignored.
The network sets the input channels and passes its ``pretrained_path`` to whichever encoder it uses.
"""

from __future__ import annotations

import importlib
from collections.abc import Mapping
from dataclasses import dataclass, fields
from typing import Any

from c3f_core.errors import InputError
from c3f_models.encoders.base import Encoder
from c3f_models.encoders.mobilenet import MobileNetEncoder
from c3f_models.encoders.resnet import ResnetConfig, ResnetEncoder

#: encoder name -> class (its settings dataclass is the class's ``config_class``)
ENCODERS: dict[str, type[Encoder]] = {"resnet": ResnetEncoder, "mobilenet_v3_small": MobileNetEncoder}

#: a field's value and the config option that sets it
Given = tuple[Any, str]


def encoder_class(name: str, option: str) -> type[Encoder]:
    """The encoder called ``name``: a key of :data:`ENCODERS`, or ``package.module.Class`` of an
    :class:`Encoder` subclass (imported); InputError naming ``option`` otherwise."""
    if name in ENCODERS:
        return ENCODERS[name]
    module, _, attr = name.rpartition(".")
    try:
        found = getattr(importlib.import_module(module), attr) if module else None
    except (ImportError, AttributeError):
        found = None
    if not (isinstance(found, type) and issubclass(found, Encoder)):
        raise InputError(f"{option} must be one of {sorted(ENCODERS)} or the class path of a "
                         f"c3f_models.encoders.Encoder subclass, got {name!r}")
    return found


@dataclass(frozen=True)
class EncoderChoice:
    """One network's encoder as its config chooses it.

    Attributes:
        cls: the encoder class.
        config: its settings (an instance of ``cls.config_class``).
        names: the config option behind each field, for the encoder's error messages.
    """

    cls: type[Encoder]
    config: Any
    names: Mapping[str, str]

    def build(self) -> Encoder:
        """The encoder, untrained (or with the ``pretrained_path`` weights)."""
        return self.cls(self.config, self.names)


def choose_encoder(name: str, option: str, options: Mapping[str, Any] | None, options_option: str,
                   resnet: Mapping[str, Given], shared: Mapping[str, Given]) -> EncoderChoice:
    """The encoder ``name`` (config option ``option``) with its settings.

    Args:
        options: the encoder's own settings (config option ``options_option``); None = its defaults.
        resnet: the ResNet settings the network config holds as flat options (field -> (value,
            option)); used by a ResNet, refused beside another encoder unless at their defaults.
        shared: fields the network sets for any encoder (``in_channels``, ``pretrained_path``).
    """
    cls = encoder_class(name, option)
    given = dict(shared)
    if issubclass(cls, ResnetEncoder):
        given.update(resnet)
    else:
        changed = [opt for field, (value, opt) in resnet.items() if value != getattr(ResnetConfig, field)]
        if changed:
            raise InputError(f"{changed[0]} is a ResNet option, but {option} is {name!r}; leave it out "
                             f"(this encoder's own settings go in {options_option})")
    options = dict(options or {})
    accepted = {f.name for f in fields(cls.config_class)}
    for key in options:
        if key in given:
            raise InputError(f"{options_option}.{key}: set by {given[key][1]}, not here")
        if key not in accepted:
            own = sorted(accepted - set(given))
            takes = f"it takes {', '.join(own)}" if own else "it has no settings of its own"
            raise InputError(f"{options_option}: {name} has no setting {key!r} ({takes})")
    config = cls.config_class(**{k: v for k, (v, _) in given.items()}, **options)
    names = {**{k: opt for k, (_, opt) in given.items()}, **{k: f"{options_option}.{k}" for k in options}}
    return EncoderChoice(cls, config, names)


__all__ = ["ENCODERS", "EncoderChoice", "choose_encoder", "encoder_class"]
