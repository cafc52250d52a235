"""c3f_models: the training side of C3Fusion (LightningModules DepthNet and ContraFeat).

Train with ``python -m c3f_models fit --config configs/...``; see ``c3f_models.cli``.
"""

__version__ = "0.1.0"
