"""DepthNet's parts: ResNet encoders (optionally deformable), disparity decoder, PoseNet, losses.

The LightningModule that ties them together is :class:`c3f_models.depthnet.DepthNet`.
"""

from c3f_models.depth.decoder import DepthDecoder, depth_to_disp, disp_to_depth
from c3f_models.depth.networks import DepthNetwork, PoseNetwork
from c3f_models.depth.objective import LossConfig, LossTerms, SelfSupervisedLoss, compose_triplet_poses
from c3f_models.depth.resnet import ResnetEncoder

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
