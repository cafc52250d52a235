"""LightningDataModules for colonoscopy sequences, the published data sets' readers, and the
procedural colon simulator.

Importing this package does not import torch; neither do ``datamodules.formats`` (the
readers), ``datamodules.convert`` / ``python -m datamodules`` (the converter) and
``datamodules.synthetic`` (the simulator). The data modules live in submodules that do:

- :mod:`datamodules.base`: frame-tuple dataset and the sequence data-module base, with its
  settings groups in :mod:`datamodules.config` (``split``, ``sampling``, ``frames``, ``loader``);
- :mod:`datamodules.sequence`: the project's own sequence layout (docs/datasets.md, Sequence layout);
- :mod:`datamodules.published`: UTS-synthetic, SimCol3D, C3VD and Colon10K as released.
"""
