"""DepthNet's settings groups besides the loss (:class:`c3f_models.depth.objective.LossConfig`)
and the optimiser (:class:`c3f_models.config.OptimConfig`). Depths are in metres."""

from __future__ import annotations

from dataclasses import dataclass

from c3f_slam.errors import InputError


@dataclass(frozen=True)
class DepthNetworkConfig:
    """Depth network and PoseNet (Monodepth2 architecture).

    Attributes:
        encoder_layers: depth encoder ResNet depth (18 for CPU, 50 in the paper).
        dcn: deformable convolutions in the depth encoder's conv3-conv5.
        pose_encoder_layers: PoseNet ResNet depth (18 in the paper).
        encoder_width: channels of the depth encoder's first stage (64: the standard ResNet; 32: a
            lighter encoder with a quarter of the weights, for CPU training and a small zoo; no
            ImageNet file fits it).
        pose_encoder_width: the same for PoseNet's encoder.
        pretrained_path: local torchvision ResNet state dict (ImageNet) for the depth encoder; null = from scratch.
        pose_pretrained_path: the same for the pose encoder.
        pose_translation_scale: metres per unit of PoseNet's raw translation output (Monodepth2: 0.01 at
            KITTI scale; 0.001 keeps the first warps' pixel motion in range with depths near 2 mm).
        min_depth: nearest depth, metres, that the sigmoid disparity maps to.
        max_depth: farthest depth, metres.
        num_scales: decoder scales used by the loss (1-4, Monodepth2 uses 4).
    """

    encoder_layers: int = 18
    dcn: bool = False
    pose_encoder_layers: int = 18
    encoder_width: int = 64
    pose_encoder_width: int = 64
    pretrained_path: str | None = None
    pose_pretrained_path: str | None = None
    pose_translation_scale: float = 1e-3
    min_depth: float = 1e-3
    max_depth: float = 0.3
    num_scales: int = 4

    def __post_init__(self) -> None:
        if not 0 < self.min_depth < self.max_depth:
            raise InputError(f"model.network.min_depth/max_depth: need 0 < min_depth < max_depth, got "
                             f"{self.min_depth}, {self.max_depth}")
        for name in ("encoder_width", "pose_encoder_width"):
            value = getattr(self, name)
            if value < 8 or value % 8:
                raise InputError(f"model.network.{name} must be a multiple of 8 (>= 8), got {value}")
        if not 1 <= self.num_scales <= 4:
            raise InputError(f"model.network.num_scales must be 1..4, got {self.num_scales}")


@dataclass(frozen=True)
class DepthEvaluationConfig:
    """Validation and test: the ground-truth range of the metrics, and TensorBoard images.

    Attributes:
        min_depth: nearest ground truth (metres) counted by the metrics; null = the network's min_depth.
        max_depth: farthest ground truth (metres) counted; null = the network's max_depth.
        log_images: samples shown in TensorBoard per validation epoch (0 = none).
    """

    min_depth: float | None = None
    max_depth: float | None = None
    log_images: int = 4


__all__ = ["DepthEvaluationConfig", "DepthNetworkConfig"]
