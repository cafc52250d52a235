"""DepthNet's colour augmentation: off by default, the same change for a sample's three frames,
only the networks' inputs (the losses see the original frames), settings checked."""

from __future__ import annotations

import pytest
import torch

from c3f_core.errors import InputError
from c3f_models.depth.augment import ColorAugmentConfig, color_augment


def _frames(b: int = 6) -> list[torch.Tensor]:
    torch.manual_seed(0)
    base = torch.rand(b, 3, 8, 8) * 0.8 + 0.1
    return [base, base.clone(), base.clone()]


def test_off_by_default_and_with_p_zero():
    f = _frames()
    assert color_augment(f, ColorAugmentConfig()) is f


def test_one_change_per_sample_for_its_three_frames():
    f = _frames()
    out = color_augment(f, ColorAugmentConfig(p=1.0, brightness=0.3, hue=0.1))
    assert torch.equal(out[0], out[1]) and torch.equal(out[1], out[2])  # equal frames stay equal
    changed = (out[0] - f[0]).abs().flatten(1).mean(1)
    assert bool((changed > 1e-3).all())  # every sample changed (p = 1)
    assert torch.equal(f[1], f[0])  # the inputs are untouched
    assert float(out[0].min()) >= 0.0 and float(out[0].max()) <= 1.0


def test_identity_factors_change_nothing():
    f = _frames()
    out = color_augment(f, ColorAugmentConfig(p=1.0, brightness=0.0, contrast=0.0, saturation=0.0, hue=0.0))
    assert torch.allclose(out[0], f[0], atol=1e-6)


def test_training_inputs_only(monkeypatch):
    from c3f_models.depth.module import DepthNet

    seen = []

    def spy(frames, cfg):
        seen.append(cfg.p)
        return frames

    monkeypatch.setattr("c3f_models.depth.module.color_augment", spy)
    net = DepthNet(network={"encoder_width": 8, "pose_encoder_width": 8, "num_scales": 1}, augment={"p": 0.5})
    batch = {"image": torch.rand(2, 3, 3, 32, 32), "K": torch.eye(3).expand(2, 3, 3) * 16}
    batch["K"] = batch["K"].clone()
    batch["K"][:, 2, 2] = 1.0
    net.compute_loss(batch, step=0)
    net.compute_loss(batch)  # validation / test: no augmentation
    assert seen == [0.5]


@pytest.mark.parametrize("field,value", [("p", 1.5), ("brightness", 1.0), ("hue", 0.6), ("noise", -0.1)])
def test_settings_are_checked(field, value):
    with pytest.raises(InputError, match=f"model.augment.{field}"):
        ColorAugmentConfig(**{field: value})


def test_noise_is_independent_per_frame_and_bounded():
    f = [torch.full((64, 3, 16, 16), 0.5) for _ in range(3)]
    torch.manual_seed(1)
    out = color_augment(f, ColorAugmentConfig(p=1.0, brightness=0.0, contrast=0.0, saturation=0.0, hue=0.0,
                                              noise=0.05))
    d = [o - g for o, g in zip(out, f)]
    assert not torch.equal(d[0], d[1])  # each frame its own noise
    std = d[0].flatten(1).std(1)  # per sample: its drawn sigma in [0, 0.05]
    assert float(std.max()) <= 0.05 * 1.1 and float(std.max()) > 0.03 and float(std.min()) < 0.02
    assert abs(float(d[0].mean())) < 2e-3  # zero-mean
    assert float(out[0].min()) >= 0.0 and float(out[0].max()) <= 1.0
