"""ContraFeat's settings groups besides the optimiser (:class:`c3f_models.config.OptimConfig`) and
the keypoint / ground-truth settings (:class:`c3f_models.contrafeat.pairs.KeypointSettings`,
:class:`~c3f_models.contrafeat.pairs.GroundTruthSettings`). Pixels are of the network input."""

from __future__ import annotations

from dataclasses import dataclass

from c3f_core.errors import InputError
from c3f_core.settings import tree_from_mapping
from c3f_models.contrafeat.loss import TAU
from c3f_models.encoders import EncoderChoice, choose_encoder
from c3f_slam.config import PRESETS, MatchFilterConfig


@dataclass(frozen=True)
class ContraFeatNetworkConfig:
    """The descriptor network (:class:`c3f_models.contrafeat.network.ContraFeatNet`, which checks the values).

    The bottom-up stream is chosen by name (docs/add_network.md); ``backbone_layers`` and
    ``backbone_width`` are the ResNet's and are refused beside another encoder.

    Attributes:
        backbone: the encoder of the bottom-up stream: ``resnet``, ``mobilenet_v3_small``
            (c3f_models.encoders.ENCODERS) or the class path of a c3f_models.encoders.Encoder subclass.
        backbone_options: that encoder's own settings besides the flat ResNet options, e.g.
            ``{width_mult: 0.75}`` for MobileNet; null = its defaults.
        backbone_layers: ResNet depth of the bottom-up stream (18 in the paper; 34 and 50 also accepted).
        backbone_width: channels of the ResNet's first stage (64: the standard ResNet; 32: a lighter
            stream with a quarter of the weights; no ImageNet file fits it).
        descriptor_dim: descriptor channels c (128 in the paper).
        fpn_channels: channels of the FPN levels.
        stem_channels: channels of the full-resolution stem that restores pixel detail.
        head_channels: hidden channels of the full-resolution 1x1 head; null = descriptor_dim.
        pretrained_path: local state dict of the backbone's torchvision model (ImageNet), or a DepthNet
            checkpoint whose depth encoder is the same network (a ResNet without DCN).
    """

    backbone: str = "resnet"
    backbone_options: dict | None = None
    backbone_layers: int = 18
    backbone_width: int = 64
    descriptor_dim: int = 128
    fpn_channels: int = 128
    stem_channels: int = 32
    head_channels: int | None = None
    pretrained_path: str | None = None

    def __post_init__(self) -> None:
        self.backbone_encoder()

    def backbone_encoder(self) -> EncoderChoice:
        """The encoder of the bottom-up stream (one RGB frame in) and its settings."""
        option = "model.network."
        return choose_encoder(self.backbone, option + "backbone", self.backbone_options, option + "backbone_options",
                              {"layers": (self.backbone_layers, option + "backbone_layers"),
                               "width": (self.backbone_width, option + "backbone_width"),
                               "dcn": (False, "the descriptor network (no deformable convolutions)")},
                              {"in_channels": (3, "the descriptor network (one RGB frame)"),
                               "pretrained_path": (self.pretrained_path, option + "pretrained_path")})


@dataclass(frozen=True)
class ContraFeatLossConfig:
    """InfoNCE over the ground-truth matches of each pair, optionally with dense correspondences.

    Attributes:
        tau: InfoNCE temperature (paper: 0.01).
        symmetric: average the i->j and j->i directions.
        dense_points: dense ground-truth correspondences per training pair added to its InfoNCE
            (0 = keypoint matches only, the paper's loss; validation and test never use them).
        dense_spacing: grid cell of the dense samples, pixels (samples >= spacing / 2 apart).
    """

    tau: float = TAU
    symmetric: bool = True
    dense_points: int = 0
    dense_spacing: int = 4

    def __post_init__(self) -> None:
        if self.tau <= 0:
            raise InputError(f"model.loss.tau must be positive, got {self.tau}")
        if self.dense_points < 0 or self.dense_spacing < 1:
            raise InputError(f"model.loss.dense_points must be >= 0 and model.loss.dense_spacing >= 1, got "
                             f"{self.dense_points}, {self.dense_spacing}")


@dataclass(frozen=True)
class MatchEvaluationConfig:
    """Validation and test matching: the keypoint filter, ratio tests and match images.

    Attributes:
        filter_preset: ``colon`` or ``room`` thresholds of the keypoint filter (MatchFilterConfig).
        filter_overrides: preset fields to change, e.g. ``{max_residual: 0.001}`` (metres).
        cdf_ratio: ratio test of the mutual-NN matching of ContraFeat descriptors; null = none.
        sift_ratio: ratio test of the mutual-NN matching of SIFT descriptors; null = none.
        num_visualisations: validation batches that log a match image (TensorBoard only).
    """

    filter_preset: str = "colon"
    filter_overrides: dict | None = None
    cdf_ratio: float | None = None
    sift_ratio: float | None = None
    num_visualisations: int = 4

    def __post_init__(self) -> None:
        self.match_filter()

    def match_filter(self) -> MatchFilterConfig:
        """The keypoint filter's thresholds: the preset with the overrides."""
        if self.filter_preset not in PRESETS:
            raise InputError(f"model.evaluation.filter_preset must be one of {tuple(PRESETS)}, "
                             f"got {self.filter_preset!r}")
        base = PRESETS[self.filter_preset].match_filter
        return tree_from_mapping(base, self.filter_overrides or {}, "model.evaluation.filter_overrides")


__all__ = ["ContraFeatLossConfig", "ContraFeatNetworkConfig", "MatchEvaluationConfig"]
