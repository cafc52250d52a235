"""DepthNet's parts: disparity decoder, depth network and PoseNet, losses (the encoders: :mod:`c3f_models.encoders`).

The LightningModule that ties them together is :class:`c3f_models.depth.module.DepthNet`.
"""

from c3f_models.depth.decoder import DepthDecoder, depth_to_disp, disp_to_depth
from c3f_models.depth.networks import DepthNetwork, PoseNetwork
from c3f_models.depth.objective import LossConfig, LossTerms, SelfSupervisedLoss, compose_triplet_poses
from c3f_models.encoders import ResnetEncoder

__all__ = [
    "DepthDecoder",
    "DepthNetwork",
    "LossConfig",
    "LossTerms",
    "PoseNetwork",
    "ResnetEncoder",
    "SelfSupervisedLoss",
    "compose_triplet_poses",
    "depth_to_disp",
    "disp_to_depth",
]
