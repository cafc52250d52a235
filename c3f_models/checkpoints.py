"""Reading checkpoints safely: weights for ``init_weights`` and export, hyper-parameters for the CLI.

Every file is read with the safe unpickler only (``torch.load(weights_only=True)``):
tensors, numbers, strings and containers. A file that needs more (pickled objects, possibly
code) is refused with an InputError; nothing in it runs. ``.safetensors`` files (the zoo's
weights; a format that holds tensors only) are read as a plain state dict.
"""

from __future__ import annotations

import importlib
import inspect
import json
import re
import zipfile
from collections.abc import Mapping
from pathlib import Path

import torch

from c3f_core.errors import InputError


def read_checkpoint(path: str | Path, option: str, mmap: bool = False) -> dict:
    """The whole checkpoint (or plain state dict) at ``path`` as the safe unpickler reads it
    (``mmap``: map the tensors instead of reading them, for a look at the other entries)."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{option}: file not found: {path}")
    if path.suffix == ".safetensors":
        return {"state_dict": read_safetensors(path, option)}
    if not zipfile.is_zipfile(path):  # torch.save writes a zip archive
        raise InputError(f"{option}: {path} is not a torch checkpoint")
    try:
        ckpt = torch.load(path, map_location="cpu", weights_only=True, mmap=mmap)
    except Exception as exc:  # noqa: BLE001 (unpickling, zip and format errors all mean: refused)
        found = re.search(r"Unsupported global: GLOBAL (\S+)", str(exc))
        what = f" (it pickles {found.group(1)})" if found else f" ({type(exc).__name__})"
        raise InputError(f"{option}: {path} needs more than the safe loader (weights_only=True) reads{what}; "
                         "refused, nothing in it ran") from None
    return ckpt if isinstance(ckpt, dict) else {}


def read_safetensors(path: Path, option: str) -> dict[str, torch.Tensor]:
    """The tensors of a ``.safetensors`` file (any dtype, as stored)."""
    from safetensors import SafetensorError
    from safetensors.torch import load_file

    try:
        return load_file(str(path), device="cpu")
    except (SafetensorError, OSError, ValueError) as exc:
        raise InputError(f"{option}: {path} is not a readable safetensors file ({str(exc).splitlines()[0]})") from None


def read_checkpoint_weights(path: str | Path, option: str = "model.init_weights") -> dict[str, torch.Tensor]:
    """Model weights from a Lightning checkpoint (``state_dict`` key) or a plain state dict file."""
    ckpt = read_checkpoint(path, option)
    state = ckpt.get("state_dict", ckpt)
    if not isinstance(state, dict) or not state or not all(isinstance(v, torch.Tensor) for v in state.values()):
        raise InputError(f"{option}: {path} holds no model weights")
    return state


def load_weights(
    module: torch.nn.Module, state: dict[str, torch.Tensor], path: str | Path, option: str,
    what: str = "the model", hint: str = "",
) -> None:
    """Load ``state`` into ``module`` strictly; InputError naming ``option`` and ``path`` with
    the numbers of missing, unexpected and wrong-shaped keys when it does not fit."""
    own = module.state_dict()
    missing = [k for k in own if k not in state]
    unexpected = [k for k in state if k not in own]
    wrong = [k for k in own if k in state and state[k].shape != own[k].shape]
    if missing or unexpected or wrong:
        example = (missing or unexpected or wrong)[0]
        raise InputError(
            f"{option}: {path} does not fit {what} ({len(missing)} missing, {len(unexpected)} unexpected, "
            f"{len(wrong)} wrong-shaped keys, e.g. {example})" + (f"; {hint}" if hint else "")
        )
    module.load_state_dict(state)


def _flat(options: Mapping, prefix: str = "") -> dict[str, str]:
    """Dotted option names -> JSON text of their values (tuples as lists), groups flattened."""
    out: dict[str, str] = {}
    for key, value in options.items():
        if str(key).startswith("_"):
            continue
        name = f"{prefix}{key}"
        if isinstance(value, Mapping):
            out.update(_flat(value, f"{name}."))
        else:
            out[name] = json.dumps(value, default=str)
    return out


#: options a resumed run may change: they only matter when a run starts
RESUME_FREE = {"init_weights"}


def check_checkpoint(path: str | Path, class_path: str | None, given: Mapping | None = None,
                     option: str = "--ckpt_path") -> None:
    """InputError (one line) unless LightningCLI may apply the checkpoint at ``path``.

    LightningCLI re-applies a ``--ckpt_path``'s saved class and hyper-parameters to the model
    (``test``, ``export`` and resumed ``fit``). Refused here, before anything runs: options of
    the layout before the options were grouped (flat ``encoder_layers``, ``lambda_dc``, ...); a
    class other than the config's ``class_path`` (a DepthNet config would export a ContraFeat);
    and for a resumed ``fit`` (``given``: the configured model options) a configuration that
    changes the saved options (the resumed run would drop them without a word).
    """
    saved = read_checkpoint(path, option, mmap=True).get("hyper_parameters") or {}
    _check_layout(saved, path, class_path, option)
    saved_class = saved.get("_class_path")
    if saved_class and class_path and saved_class != class_path:
        raise InputError(f"{option}: {path} holds a {saved_class.rpartition('.')[2]} ({saved_class}), but the "
                         f"config's model is {class_path}; refused, nothing was written")
    if given is not None:
        _check_resume(saved, given, option)


def _check_layout(saved: Mapping, path: str | Path, class_path: str | None, option: str) -> None:
    """Every saved hyper-parameter must be an argument of the model class: the checkpoint's own
    (``_class_path``, saved by the CLI) or else the config's; one that cannot be imported is
    left to Lightning."""
    module_name, _, name = str(saved.get("_class_path") or class_path or "").rpartition(".")
    try:
        model_class = getattr(importlib.import_module(module_name), name)
    except (ImportError, AttributeError, ValueError):
        return
    accepted = set(inspect.signature(model_class.__init__).parameters) - {"self"}
    unknown = sorted(k for k in saved if not str(k).startswith("_") and k not in accepted)
    if unknown:
        shown = ", ".join(unknown[:4]) + (", ..." if len(unknown) > 4 else "")
        raise InputError(
            f"{option}: {path} holds model options {name} no longer takes ({shown}; saved before "
            f"the options were grouped into {', '.join(sorted(accepted))}); refused: retrain, or start from its "
            "weights with --model.init_weights"
        )


def _check_resume(saved: Mapping, given: Mapping, option: str) -> None:
    """The configured model options of a resumed run must equal the saved ones (but :data:`RESUME_FREE`)."""
    before, after = _flat(saved), _flat(given)
    changed = sorted(k for k in before.keys() & after.keys() if before[k] != after[k] and k not in RESUME_FREE)
    if changed:
        shown = "; ".join(f"model.{k}: {before[k]} in the checkpoint, {after[k]} given" for k in changed[:3])
        raise InputError(f"{option}: a resumed run keeps the checkpoint's model options, but the configuration "
                         f"changes them ({shown}{'; ...' if len(changed) > 3 else ''}); drop those overrides, or "
                         "start a new run from its weights with --model.init_weights")


__all__ = ["check_checkpoint", "load_weights", "read_checkpoint", "read_checkpoint_weights"]
