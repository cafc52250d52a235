"""ContraFeat: network, descriptor sampling, InfoNCE, pair data, smoke fits (module and CLI)."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import lightning as L
import numpy as np
import pytest
import torch
import torchvision

from c3f_core.errors import InputError
from c3f_models.cli import main
from c3f_models.config import OptimConfig
from c3f_models.contrafeat.config import ContraFeatLossConfig, ContraFeatNetworkConfig, MatchEvaluationConfig
from c3f_models.contrafeat.loss import batch_info_nce, info_nce
from c3f_models.contrafeat.module import METHODS, ContraFeat
from c3f_models.contrafeat.network import ContraFeatNet, sample_descriptors
from c3f_models.contrafeat.pairs import GroundTruthSettings, KeypointSettings
from c3f_slam.io import Sequence
from c3f_slam.matching import sample_descriptor_map
from datamodules.config import FramesConfig, LoaderConfig
from datamodules.pairs import ContraFeatDataModule, GapPairDataset, PairSamplingConfig

ROOT = Path(__file__).resolve().parents[1]
TINY = dict(fpn_channels=16, stem_channels=8, head_channels=32)


def tiny_net(pretrained_path: Path | None = None) -> ContraFeatNet:
    """A ContraFeatNet with narrow FPN, stem and head (128-d descriptors)."""
    return ContraFeatNet(ContraFeatNetworkConfig(pretrained_path=pretrained_path, **TINY))


@pytest.fixture(autouse=True)
def _threads():
    torch.manual_seed(0)


def test_network_full_resolution_unit_norm():
    net = tiny_net().eval()
    x = torch.rand(2, 3, 45, 61)  # not a multiple of 32
    with torch.no_grad():
        y = net(x)
    assert y.shape == (2, 128, 45, 61)
    torch.testing.assert_close(y.norm(dim=1), torch.ones(2, 45, 61), atol=1e-5, rtol=0)
    with pytest.raises(InputError):
        net(torch.rand(1, 1, 32, 32))


def test_sample_descriptors_pixel_centres():
    d = torch.nn.functional.normalize(torch.randn(8, 5, 7), dim=0)
    xy = torch.tensor([[0.0, 0.0], [6.0, 4.0], [3.0, 2.0]])
    out = sample_descriptors(d, xy)
    torch.testing.assert_close(out, torch.stack([d[:, 0, 0], d[:, 4, 6], d[:, 2, 3]]))
    mid = sample_descriptors(d, torch.tensor([[2.5, 1.0]]))[0]
    torch.testing.assert_close(mid, torch.nn.functional.normalize(d[:, 1, 2] + d[:, 1, 3], dim=0))
    assert sample_descriptors(d, torch.zeros(0, 2)).shape == (0, 8)
    # the torch-free twin used by the SLAM runtime agrees (inside and beyond the border)
    pts = torch.tensor([[0.3, 0.7], [5.9, 3.2], [2.5, 1.0], [-1.0, 9.0]])
    twin = sample_descriptor_map(d.numpy(), pts.numpy())
    np.testing.assert_allclose(twin, sample_descriptors(d, pts).numpy(), atol=1e-6)


def test_info_nce_lower_for_matching_than_shuffled():
    z = torch.nn.functional.normalize(torch.randn(50, 128), dim=1)
    z_b = torch.nn.functional.normalize(z + 0.1 * torch.randn(50, 128), dim=1)
    matched = info_nce(z, z_b)
    shuffled = info_nce(z, z_b[torch.randperm(50)])
    assert matched < 0.05 < shuffled
    # one-directional, per-match values and tau
    assert info_nce(z, z_b, symmetric=False, reduction="none").shape == (50,)
    same = torch.eye(4)
    assert info_nce(same, same, tau=0.01) < 1e-30 + 1e-6
    assert torch.isclose(info_nce(torch.ones(3, 4) / 2, torch.ones(3, 4) / 2), torch.log(torch.tensor(3.0)))
    loss, n = batch_info_nce([(z[:1], z_b[:1]), (z, z_b), (z[:10], z_b[:10])])
    assert n == 60 and torch.isclose(loss, (info_nce(z, z_b) * 50 + info_nce(z[:10], z_b[:10]) * 10) / 60)
    assert batch_info_nce([(z[:1], z_b[:1])]) == (None, 0)


def test_pretrained_weights_local_file(tmp_path):
    with pytest.raises(InputError, match="file not found"):
        tiny_net(tmp_path / "missing.pth")
    bad = tmp_path / "bad.pth"
    bad.write_text("not weights")
    with pytest.raises(InputError, match="not a torch weights file"):
        tiny_net(bad)
    r34 = tmp_path / "r34.pth"
    torch.save(torchvision.models.resnet34(weights=None).state_dict(), r34)
    with pytest.raises(InputError, match="does not fit"):
        tiny_net(r34)
    ref = torchvision.models.resnet18(weights=None)
    good = tmp_path / "r18.pth"
    torch.save(ref.state_dict(), good)
    net = tiny_net(good)
    torch.testing.assert_close(net.encoder.layer3[0].conv1.weight, ref.layer3[0].conv1.weight)


@pytest.mark.parametrize("dcn", [False, True])
def test_pretrained_from_depthnet_checkpoint(tmp_path, dcn):
    """A DepthNet checkpoint's depth encoder starts ContraFeat (a DCN encoder does not fit)."""
    from c3f_models.depth.module import DepthNet

    depth = DepthNet({"encoder_layers": 18, "dcn": dcn, "pose_encoder_layers": 18})
    ckpt = tmp_path / "depthnet.ckpt"
    torch.save({"state_dict": depth.state_dict(), "global_step": 3}, ckpt)
    if dcn:
        with pytest.raises(InputError, match="unexpected keys"):
            tiny_net(ckpt)
        return
    net = tiny_net(ckpt)
    enc = depth.depth_net.encoder
    torch.testing.assert_close(net.encoder.layer4[1].conv2.weight, enc.layer4[1].conv2.weight)
    torch.testing.assert_close(net.encoder.bn1.running_var, enc.bn1.running_var)
    torch.testing.assert_close(net.encoder.conv1.weight, enc.conv1.weight)


def test_gap_pairs(plane_dataset):
    seqs = [Sequence(p) for p in sorted(plane_dataset.iterdir())]
    plain = FramesConfig(size=None, specular=False)
    train = GapPairDataset(seqs, PairSamplingConfig(gaps=(1, 2, 4, 8)), plain, train=True)
    assert train.gaps == [1, 2, 4]  # 6-frame sequences: gap 8 fits none
    gaps = {train[k]["gap"] for k in range(len(train)) for _ in range(3)}
    assert gaps == {1, 2, 4}
    s = train[0]
    assert s["image"].shape[:2] == (2, 3) and s["depth"].shape[:2] == (2, 1) and s["pose"].shape == (2, 4, 4)
    assert s["frame_index"][1] - s["frame_index"][0] == s["gap"]
    ev = GapPairDataset(seqs, PairSamplingConfig(gaps=(1, 4)), plain, train=False)
    assert len(ev) == 3 * (5 + 2) and [ev[k]["gap"] for k in (0, len(ev) - 1)] == [1, 4]
    with pytest.raises(InputError, match="long enough"):
        GapPairDataset(seqs, PairSamplingConfig(gaps=(6,)), FramesConfig(size=None), train=True)


def _module(**groups) -> ContraFeat:
    small = {"network": TINY, "keypoints": KeypointSettings(max_keypoints=96, contrast_threshold=0.01),
             "evaluation": MatchEvaluationConfig(num_visualisations=1)}
    return ContraFeat(**{**small, **groups})


@pytest.mark.e2e
def test_module_fit_and_test_in_process(plane_dataset, tmp_path):
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    dm = ContraFeatDataModule(str(plane_dataset), sampling=PairSamplingConfig(gaps=(1, 2), eval_stride=3),
                              frames=FramesConfig(size=(48, 48)), loader=LoaderConfig(batch_size=2))
    model = _module()
    logger = L.pytorch.loggers.TensorBoardLogger(str(tmp_path), name="tb")
    trainer = L.Trainer(max_steps=2, limit_train_batches=2, limit_val_batches=1, limit_test_batches=2,
                        num_sanity_val_steps=0, accelerator="cpu", logger=logger, enable_checkpointing=False,
                        log_every_n_steps=1, enable_progress_bar=False, enable_model_summary=False)
    trainer.fit(model, dm)
    m = trainer.callback_metrics
    assert torch.isfinite(m["train/loss"]) and m["train/matches"] > 5
    assert {"val/loss", "val/cdf_recall", "val/sift_kpf_precision"} <= set(m)
    out = trainer.test(model, dm, verbose=False)[0]
    for name in METHODS:
        assert 0 <= out[f"test/{name}_recall"] <= 1 and 0 <= out[f"test/{name}_precision"] <= 1
    assert out["test/sift_precision"] > 0.5  # small motion over a textured plane
    for name in METHODS:  # near misses only add to the precision; nan where nothing was found
        near, prec = out[f"test/{name}_near_precision"], out[f"test/{name}_precision"]
        assert math.isnan(near) or prec <= near <= 1
        share, lonely = out[f"test/{name}_near_miss_share"], out[f"test/{name}_no_counterpart_share"]
        assert math.isnan(share) or 0 <= lonely <= share <= 1
    model.eval()
    desc = model.describe(torch.rand(3, 48, 48), np.array([[3.0, 4.0], [20.5, 30.25]]))
    assert desc.shape == (2, 128) and torch.allclose(desc.norm(dim=1), torch.ones(2))
    events = EventAccumulator(str(Path(logger.log_dir))).Reload()
    assert "val/matches_0" in events.Tags()["images"]


def test_module_rejects_bad_options():
    with pytest.raises(InputError, match="'galaxy'"):
        MatchEvaluationConfig(filter_preset="galaxy")
    with pytest.raises(InputError, match="unknown setting 'model.evaluation.filter_overrides.no_such'"):
        _module(evaluation={"filter_overrides": {"no_such": 1}})
    with pytest.raises(InputError, match="model.loss.tau must be positive"):
        _module(loss={"tau": 0.0})
    with pytest.raises(InputError, match="model.keypoints.max_keypoints must be >= 2"):
        KeypointSettings(max_keypoints=1)
    with pytest.raises(InputError, match="model.ground_truth.pixel_radius"):
        GroundTruthSettings(pixel_radius=0)
    with pytest.raises(InputError, match="model.loss.dense_points must be >= 0"):
        ContraFeatLossConfig(dense_points=-1)
    with pytest.raises(InputError, match="model.network: .*unexpected keyword argument 'max_keypoints'"):
        _module(network={"max_keypoints": 3})


def test_groups_default_to_the_modules_defaults():
    """A partly given group (a dict) keeps the module's defaults for the rest, as the CLI does;
    the optimiser's default is ContraFeat's own (lr 3e-4, constant), not DepthNet's."""
    model = ContraFeat(network=TINY, optim={"lr": 1e-3})
    assert model.optim_config == OptimConfig(lr=1e-3, weight_decay=1e-4, milestones=())
    assert isinstance(model.configure_optimizers(), torch.optim.AdamW)  # no milestones: no scheduler
    assert model.kp_settings == KeypointSettings() and model.loss_config.tau == 0.01
    assert model.dense_settings.border == model.kp_settings.border
    assert model.hparams["optim"]["lr"] == 1e-3 and isinstance(model.hparams["keypoints"], dict)


@pytest.mark.e2e
def test_cli_smoke_fit_small_config(plane_dataset, tmp_path, monkeypatch):
    monkeypatch.setattr(sys, "argv", ["c3f_models"])
    main([
        "fit", "--config", str(ROOT / "configs/trainer/cpu_smoke.yaml"),
        "--config", str(ROOT / "configs/contrafeat/small.yaml"),
        "--data.data_dir", str(plane_dataset), "--data.frames.size", "[48, 48]", "--data.sampling.gaps", "[1, 2]",
        "--trainer.max_steps", "2", "--trainer.limit_val_batches", "1",
        "--trainer.default_root_dir", str(tmp_path), "--trainer.logger.init_args.save_dir", str(tmp_path),
    ])
    assert list(tmp_path.rglob("config.yaml")) and list(tmp_path.rglob("last.ckpt"))


@pytest.mark.parametrize("name", ["full", "small"])
def test_configs_parse(name, monkeypatch):
    monkeypatch.setattr(sys, "argv", ["c3f_models"])
    cli = main(["--config", str(ROOT / f"configs/contrafeat/{name}.yaml"), "--trainer.logger", "false"], run=False)
    assert isinstance(cli.model, ContraFeat) and isinstance(cli.datamodule, ContraFeatDataModule)
    assert cli.model.network_config.descriptor_dim == 128 and cli.model.loss_config.tau == 0.01
    assert cli.model.hparams["network"]["descriptor_dim"] == 128  # saved as plain values
    assert cli.model.loss_config.dense_points == (512 if name == "small" else 0)
    assert list(cli.model.optim_config.milestones) == ([] if name == "small" else [16, 24, 32])


def _plane_frames(tx: float = 0.0, depth_j_scale: float = 1.0):
    """Two 40x48 frames of a fronto-parallel plane at 0.05 m; camera j moved by tx (metres) along x."""
    from c3f_models.contrafeat.pairs import Frame

    h, w, z = 40, 48, 0.05
    K = np.array([[40.0, 0, 23.5], [0, 40.0, 19.5], [0, 0, 1]])
    pose_j = np.eye(4)
    pose_j[0, 3] = tx
    img = np.zeros((h, w, 3), np.uint8)
    fi = Frame(img, np.full((h, w), z, np.float32), K, np.eye(4))
    fj = Frame(img, np.full((h, w), z * depth_j_scale, np.float32), K, pose_j)
    return fi, fj


def test_dense_correspondences_follow_the_true_motion():
    from c3f_models.contrafeat.pairs import DenseSettings, GroundTruthSettings, dense_correspondences

    settings, gt = DenseSettings(points=60, spacing=4, border=2), GroundTruthSettings()
    rng = np.random.default_rng(0)
    fi, fj = _plane_frames()
    xy, uv = dense_correspondences(fi, fj, settings, gt, rng)
    assert len(xy) == 60 and np.allclose(xy, uv)  # identity pose: every pixel maps to itself
    gaps = np.linalg.norm(xy[:, None] - xy[None], axis=2) + 1e3 * np.eye(len(xy))
    assert gaps.min() >= 2.0  # at least spacing / 2 apart
    assert xy.min() >= 2 and xy[:, 0].max() <= 47 - 2 and xy[:, 1].max() <= 39 - 2
    # camera moved +5 mm along x at 50 mm depth: the scene shifts by -fx * tx / z = -4 px
    fi, fj = _plane_frames(tx=0.005)
    xy, uv = dense_correspondences(fi, fj, DenseSettings(points=500), gt, rng)
    assert len(xy) > 50
    np.testing.assert_allclose(uv - xy, np.tile([-4.0, 0.0], (len(xy), 1)), atol=1e-9)
    assert uv[:, 0].min() >= 2  # samples leaving the view (or the border) are dropped
    # j sees another surface there (depth disagrees by 30 %): occluded, no correspondence
    fi, fj = _plane_frames(depth_j_scale=0.7)
    assert len(dense_correspondences(fi, fj, settings, gt, rng)[0]) == 0
    # highlights: none sampled on i's, none landing on j's
    fi, fj = _plane_frames()
    fi.specular = np.zeros((40, 48), bool)
    fi.specular[:, :24] = True
    fj.specular = np.zeros((40, 48), bool)
    fj.specular[:20] = True
    xy, uv = dense_correspondences(fi, fj, DenseSettings(points=500), gt, rng)
    assert len(xy) > 0 and (xy[:, 0] >= 24).all() and (np.rint(uv[:, 1]) >= 20).all()
    xy_all, _ = dense_correspondences(fi, fj, DenseSettings(points=500), gt, rng, mask_specular=False)
    assert len(xy_all) > 2 * len(xy)


def test_module_dense_points_join_the_training_loss(plane_dataset):
    dm = ContraFeatDataModule(str(plane_dataset), sampling=PairSamplingConfig(gaps=(1, 2)),
                              frames=FramesConfig(size=(48, 48)), loader=LoaderConfig(batch_size=2))
    dm.setup("fit")
    batch = next(iter(dm.train_dataloader()))
    plain, dense = _module(), _module(loss=ContraFeatLossConfig(dense_points=64))
    dense.load_state_dict(plain.state_dict())
    torch.manual_seed(1)
    loss_kp, _, pairs_kp, _ = plain._loss(batch, sift_descriptors=False, dense=True)
    loss_d, _, pairs_d, stats = dense._loss(batch, sift_descriptors=False, dense=True)
    assert all(p.dense is None for p in pairs_kp) and all(p.dense is not None for p in pairs_d)
    assert 20 < stats["dense"] <= 64 and [len(p.gt) for p in pairs_kp] == [len(p.gt) for p in pairs_d]
    assert not torch.isclose(loss_kp, loss_d)  # more positives and negatives: another loss
    # evaluation losses never use them: the same as the paper's loss
    loss_eval, _, pairs_eval, _ = dense._loss(batch, sift_descriptors=False)
    assert all(p.dense is None for p in pairs_eval) and torch.isclose(loss_eval, loss_kp)
    loss_d.backward()
    assert dense.net.head[0].weight.grad.abs().sum() > 0
    with pytest.raises(InputError, match="dense_points"):
        _module(loss={"dense_points": -1})
    with pytest.raises(InputError, match="dense_spacing"):
        _module(loss={"dense_spacing": 0})


def test_colour_augmentation_changes_each_frame_on_its_own(plane_dataset):
    """model.augment: in training the network sees each frame of a pair after its own colour
    change; keypoints and ground-truth matches come from the original frames; evaluation sees
    the originals."""
    dm = ContraFeatDataModule(str(plane_dataset), sampling=PairSamplingConfig(gaps=(1, 2)),
                              frames=FramesConfig(size=(48, 48)), loader=LoaderConfig(batch_size=2))
    dm.setup("fit")
    batch = next(iter(dm.train_dataloader()))
    plain, aug = _module(), _module(augment={"p": 1.0, "brightness": 0.5, "hue": 0.2})
    aug.load_state_dict(plain.state_dict())
    seen = []
    forward = aug.net.forward
    aug.net.forward = lambda x: (seen.append(x.detach().clone()), forward(x))[1]
    torch.manual_seed(1)
    loss_a, _, pairs_a, _ = aug._loss(batch, sift_descriptors=False, dense=True, augment=True)
    torch.manual_seed(1)
    loss_p, _, pairs_p, _ = plain._loss(batch, sift_descriptors=False, dense=True, augment=True)
    images = batch["image"]
    x = seen[0].view(images.shape)
    assert not torch.allclose(x, images)
    ratio = x.mean(dim=(2, 3, 4)) / images.mean(dim=(2, 3, 4))  # (B, F): each frame its own brightness
    assert (ratio[:, 0] - ratio[:, 1]).abs().max() > 1e-3
    assert [p.gt.tolist() for p in pairs_a] == [p.gt.tolist() for p in pairs_p]
    assert not torch.isclose(loss_a, loss_p)
    seen.clear()
    aug._loss(batch, sift_descriptors=True)
    assert torch.equal(seen[0].view(images.shape), images)
    with pytest.raises(InputError, match="model.augment.p"):
        _module(augment={"p": 2.0})


def test_old_class_path_of_the_data_module_still_loads():
    """Configs saved before the data module moved name c3f_models.contrafeat.data (one release)."""
    import importlib

    old = importlib.import_module("c3f_models.contrafeat.data")
    assert old.ContraFeatDataModule is ContraFeatDataModule and old.PairSamplingConfig is PairSamplingConfig
