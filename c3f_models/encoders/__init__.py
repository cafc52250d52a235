"""Encoders: the image backbones of the depth, pose and descriptor networks (docs/add_network.md).

Every encoder is an :class:`Encoder`: (B, 3 x frames, H, W) RGB in [0, 1] -> 5 feature maps at
strides 2, 4, 8, 16, 32, channels in ``num_ch_enc``. A network config chooses one by name
(:data:`ENCODERS`: ``resnet``, the default, and ``mobilenet_v3_small``) or by class path, see
:func:`choose_encoder`.
"""

from c3f_models.encoders.base import STRIDES, Encoder
from c3f_models.encoders.features import FeaturesEncoder
from c3f_models.encoders.mobilenet import MobileNetConfig, MobileNetEncoder
from c3f_models.encoders.registry import ENCODERS, EncoderChoice, choose_encoder, encoder_class
from c3f_models.encoders.resnet import ResnetConfig, ResnetEncoder

__all__ = [
    "ENCODERS",
    "STRIDES",
    "Encoder",
    "EncoderChoice",
    "FeaturesEncoder",
    "MobileNetConfig",
    "MobileNetEncoder",
    "ResnetConfig",
    "ResnetEncoder",
    "choose_encoder",
    "encoder_class",
]
