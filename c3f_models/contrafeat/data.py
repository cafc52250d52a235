"""Former home of the ContraFeat data module, now :mod:`datamodules.pairs` (with the other data
modules). This alias keeps configs saved before the move (``class_path:
c3f_models.contrafeat.data.ContraFeatDataModule``, e.g. a run's ``config.yaml``) working for one
release; new configs name ``datamodules.pairs.ContraFeatDataModule``."""

from datamodules.pairs import ContraFeatDataModule, GapPairDataset, PairSamplingConfig

__all__ = ["ContraFeatDataModule", "GapPairDataset", "PairSamplingConfig"]
