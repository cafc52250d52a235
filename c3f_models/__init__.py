"""c3f_models: the training side of C3Fusion (LightningModules DepthNet and ContraFeat).

Train with ``python -m c3f_models fit --config ...``; see ``c3f_models.cli``.
``from c3f_models import DepthNet, ContraFeat`` imports a module only when it is asked for,
so that importing the package (and the CLI's ``--help``) stays fast.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from c3f_models.contrafeat.module import ContraFeat
    from c3f_models.depth.module import DepthNet

from c3f_slam import __version__  # the one project version (exports record it)

#: public name -> the module that defines it (imported on first access)
LAZY_EXPORTS = {"DepthNet": "c3f_models.depth.module", "ContraFeat": "c3f_models.contrafeat.module"}


def __getattr__(name: str) -> Any:
    module = LAZY_EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value  # later look-ups skip this function
    return value


def __dir__() -> list[str]:
    return sorted([*globals(), *LAZY_EXPORTS])


__all__ = ["ContraFeat", "DepthNet", "__version__"]
