"""DepthNet's settings groups besides the loss (:class:`c3f_models.depth.objective.LossConfig`)
and the optimiser (:class:`c3f_models.config.OptimConfig`). Depths are in metres."""

from __future__ import annotations

from dataclasses import dataclass

from c3f_core.errors import InputError
from c3f_models.encoders import EncoderChoice, choose_encoder

OPTION = "model.network."  # the group's options in a config


@dataclass(frozen=True)
class DepthNetworkConfig:
    """Depth network and PoseNet (Monodepth2 architecture).

    The encoders are chosen by name (docs/add_network.md); the flat ``encoder_*``, ``pose_encoder_*``
    and ``dcn`` options are the ResNet's and are refused beside another encoder.

    Attributes:
        encoder: the depth encoder: ``resnet``, ``mobilenet_v3_small`` (c3f_models.encoders.ENCODERS)
            or the class path of a c3f_models.encoders.Encoder subclass.
        pose_encoder: PoseNet's encoder, the same choices (it takes two frames, 6 channels).
        encoder_options: the depth encoder's own settings besides the flat ResNet options, e.g.
            ``{width_mult: 0.75}`` for MobileNet; null = its defaults.
        pose_encoder_options: the same for PoseNet's encoder.
        encoder_layers: depth encoder ResNet depth (18 for CPU, 50 in the paper).
        dcn: deformable convolutions in the depth encoder's conv3-conv5.
        pose_encoder_layers: PoseNet ResNet depth (18 in the paper).
        encoder_width: channels of the depth encoder's first stage (64: the standard ResNet; 32: a
            lighter encoder with a quarter of the weights, for CPU training and a small zoo; no
            ImageNet file fits it).
        pose_encoder_width: the same for PoseNet's encoder.
        pretrained_path: local state dict of the depth encoder's torchvision model (ImageNet), or a
            DepthNet checkpoint; null = from scratch.
        pose_pretrained_path: the same for the pose encoder (first conv repeated for the two frames).
        pose_translation_scale: metres per unit of PoseNet's raw translation output (Monodepth2: 0.01 at
            KITTI scale; 0.001 keeps the first warps' pixel motion in range with depths near 2 mm).
        min_depth: nearest depth, metres, that the sigmoid disparity maps to.
        max_depth: farthest depth, metres.
        num_scales: decoder scales used by the loss (1-4, Monodepth2 uses 4).
    """

    encoder: str = "resnet"
    pose_encoder: str = "resnet"
    encoder_options: dict | None = None
    pose_encoder_options: dict | None = None
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
        self.depth_encoder()
        self.posenet_encoder()

    def depth_encoder(self) -> EncoderChoice:
        """The depth network's encoder (one RGB frame in) and its settings."""
        return choose_encoder(self.encoder, OPTION + "encoder", self.encoder_options, OPTION + "encoder_options",
                              {"layers": (self.encoder_layers, OPTION + "encoder_layers"),
                               "width": (self.encoder_width, OPTION + "encoder_width"),
                               "dcn": (self.dcn, OPTION + "dcn")},
                              {"in_channels": (3, "the depth network (one RGB frame)"),
                               "pretrained_path": (self.pretrained_path, OPTION + "pretrained_path")})

    def posenet_encoder(self) -> EncoderChoice:
        """PoseNet's encoder (two RGB frames stacked, 6 channels in) and its settings."""
        return choose_encoder(self.pose_encoder, OPTION + "pose_encoder", self.pose_encoder_options,
                              OPTION + "pose_encoder_options",
                              {"layers": (self.pose_encoder_layers, OPTION + "pose_encoder_layers"),
                               "width": (self.pose_encoder_width, OPTION + "pose_encoder_width"),
                               "dcn": (False, "PoseNet (no deformable convolutions)")},
                              {"in_channels": (6, "PoseNet (two RGB frames)"),
                               "pretrained_path": (self.pose_pretrained_path, OPTION + "pose_pretrained_path")})


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
