"""Encoder weights from a local file (nothing is downloaded), checked key by key before loading.

A file holds a state dict (plain, or under a ``state_dict`` key): a torchvision model's
``state_dict`` (``torch.save(torchvision.models.resnet18(weights=...).state_dict(), path)``), or a
DepthNet checkpoint, whose depth encoder (keys ``depth_net.encoder.*``) is the part that loads,
e.g. to start ContraFeat from an encoder trained self-supervised on colon video.
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

import torch
from torch import nn

from c3f_core.errors import InputError

DEPTH_ENCODER_PREFIX = "depth_net.encoder."  # DepthNet's depth encoder inside its LightningModule state


def read_state_dict(path: str | Path, option: str) -> dict[str, torch.Tensor]:
    """Read a state dict (plain, or under a ``state_dict`` key) from a local file; InputError if unusable."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{option}: file not found: {path}")
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # pickle, zip or format errors all mean "not a weights file"
        raise InputError(f"{option}: {path} is not a torch weights file ({type(exc).__name__})") from None
    if isinstance(state, dict) and isinstance(state.get("state_dict"), dict):
        state = state["state_dict"]
    if not isinstance(state, dict) or not state or not all(isinstance(v, torch.Tensor) for v in state.values()):
        raise InputError(f"{option}: {path} does not hold a state dict (name -> tensor)")
    return dict(state)


def encoder_weights(state: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """The encoder part of a state dict: a torchvision state dict as is, or a DepthNet checkpoint's depth encoder."""
    if any(k.startswith(DEPTH_ENCODER_PREFIX) for k in state):
        n = len(DEPTH_ENCODER_PREFIX)
        return {k[n:]: v for k, v in state.items() if k.startswith(DEPTH_ENCODER_PREFIX)}
    return state


def load_pretrained(target: nn.Module, path: str | Path, option: str, *, what: str, first_conv: str,
                    frames: int = 1, ignored: Iterable[str] = ()) -> None:
    """Load the weights of ``path`` into ``target`` (keys as ``target.state_dict()`` names them).

    Keys under an ``ignored`` prefix (a classifier, layers the encoder leaves out) are dropped on
    both sides. For ``frames`` > 1 stacked frames (PoseNet) the RGB filters of the first conv
    (key ``first_conv``) are repeated for every frame and divided by the number of frames
    (Monodepth2). Missing, unexpected or mis-shaped keys raise an InputError naming ``option``,
    the file and ``what`` (e.g. "this ResNet (8 residual blocks)").
    """
    prefixes = tuple(ignored)
    state = {k: v for k, v in encoder_weights(read_state_dict(path, option)).items() if not k.startswith(prefixes)}
    if frames > 1 and first_conv in state and state[first_conv].shape[1] == 3:
        state[first_conv] = torch.cat([state[first_conv]] * frames, dim=1) / frames
    own = {k: v for k, v in target.state_dict().items() if not k.startswith(prefixes)}
    missing = [k for k in own if k not in state]
    unexpected = [k for k in state if k not in own]
    wrong = [k for k in own if k in state and state[k].shape != own[k].shape]
    if missing or unexpected or wrong:
        problems = [f"{len(keys)} {label} keys (e.g. {keys[0]})"
                    for label, keys in (("missing", missing), ("unexpected", unexpected), ("wrong-shaped", wrong))
                    if keys]
        raise InputError(f"{option}: {path} does not fit {what}: " + ", ".join(problems))
    target.load_state_dict(state, strict=False)


__all__ = ["DEPTH_ENCODER_PREFIX", "encoder_weights", "load_pretrained", "read_state_dict"]
