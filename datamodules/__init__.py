"""LightningDataModules for colonoscopy sequences, and the procedural colon simulator.

Importing this package does not import torch: ``datamodules.synthetic`` (the simulator)
is torch-free. The data modules live in submodules that do import torch:

- :mod:`datamodules.base`: frame-tuple dataset and the sequence data-module base;
- :mod:`datamodules.sequence`: the project's own sequence layout (SPEC §5.2).
"""
