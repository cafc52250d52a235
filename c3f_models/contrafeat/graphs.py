"""ContraFeat's exported graph (see :mod:`export.graphs` for the conventions)."""

from __future__ import annotations

import torch
from torch import nn

from c3f_models.contrafeat.network import ContraFeatNet


class DescriptorGraph(nn.Module):
    """Unit-norm dense descriptors at the input resolution."""

    def __init__(self, net: ContraFeatNet) -> None:
        super().__init__()
        self.net = net

    def forward(self, image: torch.Tensor) -> torch.Tensor:
        return self.net(image)


__all__ = ["DescriptorGraph"]
