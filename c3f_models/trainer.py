"""The project's Trainer: Lightning's, plus room for extra CLI subcommands (``export``)."""

from __future__ import annotations

import lightning as L


class C3FTrainer(L.Trainer):
    """Lightning Trainer used by ``python -m c3f_models``.

    Extra subcommands of the CLI are methods of this class (LightningCLI calls
    ``trainer.<subcommand>(model=..., datamodule=..., ...)``).
    """
