"""DepthNet LightningModule: smoke training on the analytic plane data, logging, init weights, configs."""

from __future__ import annotations

import importlib
import math
import sys
from pathlib import Path

import lightning as L
import pytest
import torch
import yaml
from lightning.pytorch.loggers import TensorBoardLogger

from c3f_core.errors import InputError
from c3f_models.config import OptimConfig
from c3f_models.depth.config import DepthEvaluationConfig, DepthNetworkConfig
from c3f_models.depth.module import DepthNet
from c3f_models.depth.objective import LossConfig
from datamodules.config import FramesConfig, LoaderConfig
from datamodules.sequence import C3FSequenceDataModule

ROOT = Path(__file__).resolve().parents[1]
CONFIGS = ROOT / "configs" / "depthnet"
TINY = DepthNetworkConfig(encoder_layers=18, dcn=False, num_scales=2)
MONODEPTH2 = dict(use_extra_photometric=False, use_depth_consistency=False, use_outlier_mask=False,
                  use_specular_mask=False)


def datamodule(root: Path, size: int = 32, batch_size: int = 2) -> C3FSequenceDataModule:
    return C3FSequenceDataModule(data_dir=str(root), frames=FramesConfig(size=(size, size)),
                                 loader=LoaderConfig(batch_size=batch_size))


def trainer(tmp_path: Path, **kw) -> L.Trainer:
    opts = dict(accelerator="cpu", devices=1, logger=False, enable_checkpointing=False, enable_progress_bar=False,
                enable_model_summary=False, default_root_dir=tmp_path)
    opts.update(kw)
    return L.Trainer(**opts)


@pytest.mark.parametrize("switches", [{}, MONODEPTH2], ids=["c3fusion", "monodepth2"])
def test_fast_dev_run_on_planes(plane_dataset, tmp_path, switches):
    L.seed_everything(0)
    model = DepthNet(TINY, LossConfig(**switches))
    tr = trainer(tmp_path, fast_dev_run=2)
    tr.fit(model, datamodule=datamodule(plane_dataset))
    m = tr.callback_metrics
    assert math.isfinite(float(m["train/loss"])) and math.isfinite(float(m["val/loss"]))
    assert 0 < float(m["val/abs_rel"]) < 1 and 0 <= float(m["val/a1"]) <= 1
    # the collapse indicator: a random network's depth is not flat, and it is a ratio >= 0
    assert 0 < float(m["train/depth_cv"]) < 10 and 0 < float(m["val/depth_cv"]) < 10
    if switches:
        assert "train/ph_extra" not in m and "train/dc" not in m
    else:
        assert math.isfinite(float(m["train/ph_extra"])) and math.isfinite(float(m["train/dc"]))


def _overfit(root: Path, steps: int, **switches) -> list[float]:
    """Losses of ``steps`` AdamW steps of a tiny model on one batch of plane triplets."""
    torch.manual_seed(0)
    dm = datamodule(root, size=32, batch_size=4)
    dm.setup("fit")
    batch = next(iter(dm.train_dataloader()))
    model = DepthNet(DepthNetworkConfig(encoder_layers=18, num_scales=1), LossConfig(**switches))
    opt = model.configure_optimizers()["optimizer"]
    losses = []
    for _ in range(steps):
        terms, _ = model.compute_loss(batch)
        opt.zero_grad()
        terms.loss.backward()
        opt.step()
        losses.append(terms.loss.item())
    assert all(math.isfinite(v) for v in losses)
    return losses


@pytest.mark.e2e
def test_training_reduces_the_loss(plane_dataset):
    """Ten steps on one batch of plane triplets lower the full loss clearly (about 5 s)."""
    losses = _overfit(plane_dataset, 10)
    assert min(losses[-3:]) < 0.5 * losses[0], losses


@pytest.mark.slow
@pytest.mark.parametrize("switches", [{}, MONODEPTH2], ids=["c3fusion", "monodepth2"])
def test_training_reduces_the_loss_in_30_steps(plane_dataset, switches):
    losses = _overfit(plane_dataset, 30, **switches)
    assert min(losses[-5:]) < 0.2 * losses[0], losses


def test_depth_consistency_warmup(plane_dataset, tmp_path):
    """loss.lambda_dc_warmup_steps ramps the weight of L_dc in the training loss from 0 (step 0)
    to lambda_dc (from step N on); without it the training loss is the objective's."""
    torch.manual_seed(0)
    dm = datamodule(plane_dataset, size=32, batch_size=2)
    dm.setup("fit")
    batch = next(iter(dm.train_dataloader()))
    model = DepthNet(TINY, LossConfig(lambda_dc=0.1, lambda_dc_warmup_steps=4))
    assert [model.loss_config.dc_weight(s) for s in (0, 2, 4, 9)] == pytest.approx([0.0, 0.05, 0.1, 0.1])
    torch.manual_seed(1)
    terms, _ = model.compute_loss(batch)
    assert float(terms.dc.detach()) > 0 and terms.training_loss is terms.loss  # no step: no warm-up
    torch.manual_seed(1)
    at_start = model.training_step(batch, 0)  # no trainer: global_step 0
    assert float(at_start.detach()) == pytest.approx(float(terms.ph + 0.1 * terms.ph_extra), rel=1e-5)
    plain = DepthNet(TINY, LossConfig(lambda_dc=0.1))
    plain.load_state_dict(model.state_dict())
    torch.manual_seed(1)
    assert float(plain.training_step(batch, 0)) == pytest.approx(float(terms.loss), rel=1e-5)
    with pytest.raises(InputError, match="model.loss.lambda_dc_warmup_steps"):
        DepthNet(TINY, LossConfig(lambda_dc_warmup_steps=-1))
    # in a fit, the ramp follows the trainer's step and is logged
    tr = trainer(tmp_path, max_steps=3, limit_val_batches=0, log_every_n_steps=1)
    tr.fit(model, datamodule=datamodule(plane_dataset))
    assert float(tr.callback_metrics["train/lambda_dc"]) == pytest.approx(0.05)


def _without_and_with(plane_dataset, loss: LossConfig):
    """A training batch, the DepthNet with ``loss``, and the loss terms of the same network
    without the supervised terms and with them (same initial weights, same augmentation)."""
    dm = datamodule(plane_dataset, size=32, batch_size=2)
    dm.setup("fit")
    batch = next(iter(dm.train_dataloader()))
    torch.manual_seed(0)
    plain = DepthNet(TINY)
    torch.manual_seed(0)
    model = DepthNet(TINY, loss)
    torch.manual_seed(1)
    base, _ = plain.compute_loss(batch)
    torch.manual_seed(1)
    terms, _ = model.compute_loss(batch)
    return batch, model, base, terms


@pytest.mark.e2e
def test_supervised_depth_term(plane_dataset):
    """loss.lambda_gt_depth adds lambda x mean |log D - log D_gt| of frame t to both losses (off by
    default); a few steps on it lower the log-depth error; it needs true depth and lambda >= 0."""
    batch, model, base, terms = _without_and_with(plane_dataset, LossConfig(lambda_gt_depth=0.5))
    assert base.gt is None and float(terms.gt) > 0
    assert float(terms.loss) == pytest.approx(float(base.loss + 0.5 * terms.gt), rel=1e-5)
    assert terms.training_loss is terms.loss
    opt = model.configure_optimizers()["optimizer"]
    errors = []
    for _ in range(8):
        terms, _ = model.compute_loss(batch)
        opt.zero_grad()
        terms.training_loss.backward()
        opt.step()
        errors.append(float(terms.gt))
    assert errors[-1] < 0.9 * errors[0], errors  # plane depths lie beyond TINY.max_depth: slow but steady
    no_depth = {k: v for k, v in batch.items() if k != "depth"}
    with pytest.raises(InputError, match="lambda_gt_depth"):
        model.compute_loss(no_depth)
    with pytest.raises(InputError, match="lambda_gt_depth"):
        LossConfig(lambda_gt_depth=-1.0)


def test_log_gradient_matching_wants_the_steps_of_the_truth():
    """0 for the truth at any global scale; positive for a blurred step; no ground truth, no
    pairs: 0 with a gradient."""
    from c3f_models.depth.losses import log_gradient_matching

    gt = torch.full((2, 1, 32, 32), 0.03)
    gt[..., 16:] = 0.045  # a fold's crest against the wall behind it
    assert float(log_gradient_matching(gt, gt)) == 0.0
    assert float(log_gradient_matching(1.7 * gt, gt)) == pytest.approx(0.0, abs=1e-6)
    ramp = torch.exp(torch.linspace(math.log(0.03), math.log(0.045), 32)).expand(2, 1, 32, 32)
    blurred = ramp.clone().requires_grad_(True)
    loss = log_gradient_matching(blurred, gt)
    loss.backward()
    assert float(loss) > 0.01 and blurred.grad.abs().sum() > 0
    nothing = torch.zeros_like(gt)
    x = gt.clone().requires_grad_(True)
    zero = log_gradient_matching(x, nothing)
    zero.backward()
    assert float(zero) == 0.0 and x.grad is not None


def test_log_gradient_matching_at_the_edges_only():
    """edge > 0 averages over the pairs where the truth steps: errors on the flat wall do not
    count, a halved step counts in full instead of being diluted by every flat pair."""
    from c3f_models.depth.losses import log_gradient_matching

    gt = torch.full((1, 1, 32, 32), 0.03)
    gt[..., 16:] = 0.045
    noisy_wall = gt * (1 + 0.02 * torch.randn(gt.shape, generator=torch.Generator().manual_seed(0)))
    noisy_wall[..., 8:24] = gt[..., 8:24]  # exact across the step at every stride (1-8)
    assert float(log_gradient_matching(noisy_wall, gt)) > 0.005
    assert float(log_gradient_matching(noisy_wall, gt, edge=0.05)) == pytest.approx(0.0, abs=1e-6)
    halved = gt.clone()
    halved[..., 16:] = 0.03 * 1.5**0.5
    everywhere, at_edges = log_gradient_matching(halved, gt), log_gradient_matching(halved, gt, edge=0.05)
    assert float(at_edges) == pytest.approx(0.5 * math.log(1.5), rel=1e-4)  # the missing half of the step
    assert float(at_edges) > 10 * float(everywhere)
    with pytest.raises(InputError, match="gt_gradient_edge"):
        LossConfig(gt_gradient_edge=-0.1)


def test_supervised_gradient_term_joins_the_loss(plane_dataset):
    """loss.lambda_gt_gradient adds lambda x the gradient-matching term of frame t (logged apart
    from the per-pixel term); it needs true depth and lambda >= 0."""
    batch, _, base, terms = _without_and_with(plane_dataset, LossConfig(lambda_gt_depth=0.5, lambda_gt_gradient=2.0))
    assert base.gt_gradient is None and float(terms.gt_gradient) > 0 and float(terms.gt) > 0
    assert float(terms.loss) == pytest.approx(float(base.loss + 0.5 * terms.gt + 2.0 * terms.gt_gradient), rel=1e-5)
    no_depth = {k: v for k, v in batch.items() if k != "depth"}
    with pytest.raises(InputError, match="lambda_gt_gradient"):
        DepthNet(TINY, LossConfig(lambda_gt_gradient=1.0)).compute_loss(no_depth)
    with pytest.raises(InputError, match="lambda_gt_gradient"):
        LossConfig(lambda_gt_gradient=-1.0)


@pytest.mark.parametrize("step", [0, 2, 4])
def test_warmup_inside_the_objective_matches_subtracting_afterwards(plane_dataset, step):
    """The warm-up weight inside the objective gives the loss and gradients of the former way:
    the full objective minus (lambda_dc - w) * L_dc; the logged terms are unchanged."""
    dm = datamodule(plane_dataset, size=32, batch_size=2)
    dm.setup("fit")
    batch = next(iter(dm.train_dataloader()))
    torch.manual_seed(0)
    model = DepthNet(TINY, LossConfig(lambda_dc=0.1, lambda_dc_warmup_steps=4))
    params = [p for p in model.parameters() if p.requires_grad]
    terms, _ = model.compute_loss(batch)
    w = model.loss_config.dc_weight(step)
    before = terms.loss - (0.1 - w) * terms.dc
    old_grads = torch.autograd.grad(before, params, allow_unused=True)
    ramped, _ = model.compute_loss(batch, step=step)
    new_grads = torch.autograd.grad(ramped.training_loss, params, allow_unused=True)
    torch.testing.assert_close(ramped.training_loss, before, rtol=1e-6, atol=1e-9)
    for name in ("loss", "ph", "ph_extra", "dc"):  # what is logged: bit for bit the same
        assert torch.equal(getattr(ramped, name), getattr(terms, name)), name
    for a, b in zip(old_grads, new_grads):
        assert (a is None) == (b is None)
        if a is not None:
            torch.testing.assert_close(b, a, rtol=1e-5, atol=1e-9)


def test_forward_and_predict_give_metric_depth():
    model = DepthNet({"encoder_layers": 18, "num_scales": 2, "min_depth": 0.002, "max_depth": 0.2}).eval()  # a dict
    with torch.no_grad():
        depth = model(torch.rand(2, 3, 32, 40))
        pred = model.predict_step({"image": torch.rand(2, 3, 3, 32, 40)}, 0)
    assert depth.shape == (2, 1, 32, 40) and pred.shape == (2, 1, 32, 40)
    assert bool(((depth >= 0.002 - 1e-7) & (depth <= 0.2 + 1e-6)).all())
    with pytest.raises(InputError, match="frame triplets"):
        model.compute_loss({"image": torch.rand(1, 2, 3, 32, 32), "K": torch.eye(3)[None]})


def test_optimiser_and_schedule():
    model = DepthNet(TINY)
    conf = model.configure_optimizers()
    opt, sched = conf["optimizer"], conf["lr_scheduler"]["scheduler"]
    assert isinstance(opt, torch.optim.AdamW) and opt.defaults["betas"] == (0.9, 0.999)
    assert conf["lr_scheduler"]["interval"] == "epoch"
    lrs = []
    for _ in range(34):
        lrs.append(opt.param_groups[0]["lr"])
        opt.step()
        sched.step()
    assert lrs[15] == pytest.approx(1e-4) and lrs[16] == pytest.approx(5e-5)
    assert lrs[24] == pytest.approx(2.5e-5) and lrs[33] == pytest.approx(1.25e-5)
    with pytest.raises(InputError, match="model.network.min_depth"):
        DepthNet({"min_depth": 0.5, "max_depth": 0.3})
    with pytest.raises(InputError, match="model.optim: .*unexpected keyword argument 'lr_milestones'"):
        DepthNet(TINY, optim={"lr_milestones": [1]})
    constant = DepthNet(TINY, optim=OptimConfig(milestones=())).configure_optimizers()
    assert isinstance(constant, torch.optim.AdamW)  # no milestones: no scheduler


@pytest.mark.e2e
def test_tensorboard_images_metrics_and_init_weights(plane_dataset, tmp_path):
    L.seed_everything(0)
    model = DepthNet(TINY, evaluation=DepthEvaluationConfig(log_images=2))
    logger = TensorBoardLogger(tmp_path, name="tb")
    tr = trainer(tmp_path, logger=logger, max_epochs=1, limit_train_batches=1, limit_val_batches=1,
                 num_sanity_val_steps=0, log_every_n_steps=1)
    dm = datamodule(plane_dataset)
    tr.fit(model, datamodule=dm)
    ckpt = tmp_path / "model.ckpt"
    tr.save_checkpoint(ckpt)

    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    events = EventAccumulator(str(Path(logger.log_dir)), size_guidance={"images": 0}).Reload()
    assert "val/samples" in events.Tags()["images"]
    img = events.Images("val/samples")[0]
    assert img.width > 0 and img.height > 0
    scalars = events.Tags()["scalars"]
    for tag in ("train/loss", "train/ph", "train/ph_extra", "train/dc", "val/loss", "val/abs_rel", "val/rmse"):
        assert tag in scalars, tag

    tested = tr.test(model, datamodule=dm, verbose=False)[0]
    assert math.isfinite(tested["test/abs_rel"]) and "test/loss" in tested
    assert tested["test/gt_to_pred_scale"] > 0  # metres per unit of prediction (SLAM --depth-scale)

    # init_weights: loaded when fitting starts, not when the module is made
    fresh = DepthNet(TINY, init_weights=str(ckpt))
    trained = model.state_dict()
    key = "depth_net.encoder.layer1.0.conv1.weight"
    assert not torch.equal(fresh.state_dict()[key], trained[key])
    fresh.setup("fit")
    for k, v in fresh.state_dict().items():
        assert torch.equal(v, trained[k]), k
    # a module restored from a checkpoint keeps its weights (init_weights is not re-applied)
    restored = DepthNet.load_from_checkpoint(ckpt, init_weights=str(ckpt))
    assert restored._init_weights_done
    # a run with init_weights starts from them (optimiser and epoch fresh)
    tr2 = trainer(tmp_path, max_steps=1, limit_val_batches=0)
    tr2.fit(DepthNet(TINY, init_weights=str(ckpt)), datamodule=dm)
    assert tr2.global_step == 1


def test_init_weights_errors(tmp_path):
    with pytest.raises(InputError, match="model.init_weights: file not found"):
        DepthNet(TINY, init_weights=str(tmp_path / "nope.ckpt")).setup("fit")
    junk = tmp_path / "junk.ckpt"
    junk.write_text("not a checkpoint")
    with pytest.raises(InputError, match="junk.ckpt is not a torch checkpoint"):
        DepthNet(TINY, init_weights=str(junk)).setup("fit")
    other = tmp_path / "other.ckpt"
    torch.save({"state_dict": DepthNet(DepthNetworkConfig(encoder_layers=18, dcn=True, num_scales=1)).state_dict()},
               other)
    expected = "does not fit this DepthNet.*model.network.encoder_layers, encoder_width, dcn"
    with pytest.raises(InputError, match=expected):
        DepthNet(TINY, init_weights=str(other)).setup("fit")


class _Payload:
    """Unpickling this runs code: it touches a marker file."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self):
        return (Path.touch, (self.marker,))


def test_a_checkpoint_cannot_run_code(tmp_path):
    """A crafted --model.init_weights (or export --ckpt_path) is refused before anything in it runs."""
    marker = tmp_path / "payload_ran"
    crafted = tmp_path / "crafted.ckpt"
    torch.save({"state_dict": DepthNet(TINY).state_dict(), "hyper_parameters": _Payload(marker)}, crafted)
    with pytest.raises(InputError, match=r"crafted.ckpt needs more than the safe loader \(weights_only=True\) reads "
                                         r"\(it pickles \S+\); refused, nothing in it ran"):
        DepthNet(TINY, init_weights=str(crafted)).setup("fit")
    with pytest.raises(InputError, match="--ckpt_path: .*crafted.ckpt needs more than the safe loader"):
        DepthNet(TINY).load_export_checkpoint(crafted)
    assert not marker.exists(), "the payload ran"
    fn, args = _Payload(marker).__reduce__()  # the control: what an unpickler would call does touch it
    fn(*args)
    assert marker.exists()


# ---------------------------------------------------------------- configs
def _load(name: str) -> dict:
    return yaml.safe_load((CONFIGS / name).read_text())


def _instantiate(spec: dict):
    module, _, cls = spec["class_path"].rpartition(".")
    return getattr(importlib.import_module(module), cls)(**spec.get("init_args", {}))


#: the loss group of the former copies monodepth2.yaml / small_monodepth2.yaml (the default weights)
MONODEPTH2_LOSS = LossConfig(use_automask=True, use_extra_photometric=False, use_depth_consistency=False,
                             use_outlier_mask=False, use_specular_mask=False, lambda_ph_extra=0.1, lambda_dc=0.1,
                             ssim_alpha=0.85, outlier_percentile=0.8)
GROUPS = {"network": DepthNetworkConfig, "loss": LossConfig, "optim": OptimConfig, "evaluation": DepthEvaluationConfig}


@pytest.mark.parametrize("name", ["small.yaml", "full.yaml"])
def test_configs_instantiate(name):
    from dataclasses import fields

    cfg = _load(name)
    assert set(cfg) == {"trainer", "model", "data"} and set(cfg["trainer"]) == {"max_epochs"}
    data = _instantiate(cfg["data"])
    assert isinstance(data, C3FSequenceDataModule)
    args = cfg["model"]["init_args"]
    assert set(args) <= {*GROUPS, "init_weights"}
    for group, cls in GROUPS.items():  # nested groups, each with fields of its settings class only
        assert set(args.get(group, {})) <= {f.name for f in fields(cls)}, group
    if name.startswith("small"):
        model = _instantiate(cfg["model"])
        assert isinstance(model, DepthNet)
    else:  # building ResNet50+DCN takes a while: check the groups instead
        assert args["network"]["encoder_layers"] == 50 and args["network"]["dcn"] is True
        assert data.frames_config.size == (224, 224) and data.loader_config.batch_size == 16  # the defaults
        assert cfg["trainer"]["max_epochs"] == 40


@pytest.mark.parametrize("base", ["small.yaml", "full.yaml"])
def test_monodepth2_override_composes_the_baseline(base, monkeypatch):
    """monodepth2.yaml after full.yaml / small.yaml gives the Monodepth2 loss switches (those of the
    former copies) and changes nothing else: networks, optimiser, evaluation and data stay."""
    from c3f_models.cli import main

    monkeypatch.setattr(sys, "argv", ["c3f_models"])
    assert set(_load("monodepth2.yaml")) == {"model"}
    assert set(_load("monodepth2.yaml")["model"]["init_args"]) == {"loss"}
    common = ["--config", str(CONFIGS / base), "--trainer.logger", "false"]
    plain = main(common, run=False)
    baseline = main([*common, "--config", str(CONFIGS / "monodepth2.yaml")], run=False)
    assert baseline.model.loss_config == MONODEPTH2_LOSS
    assert plain.model.loss_config == LossConfig()  # the full objective
    for attr in ("network_config", "optim_config", "evaluation_config", "init_weights"):
        assert getattr(baseline.model, attr) == getattr(plain.model, attr), attr
    assert {k: v for k, v in baseline.model.hparams.items() if k != "loss"} == \
        {k: v for k, v in plain.model.hparams.items() if k != "loss"}
    assert baseline.datamodule.hparams == plain.datamodule.hparams
    assert baseline.trainer.max_epochs == plain.trainer.max_epochs == 40


def test_colorize_depth_for_tensorboard():
    from c3f_models.depth.visual import colorize_depth, panel

    depth = torch.full((2, 1, 8, 8), 0.05)
    depth[1, :, :, 4:] = 0.1
    depth[1, :, 0, 0] = 0.0  # no depth: black
    rgb = colorize_depth(depth)
    assert rgb.shape == (2, 3, 8, 8) and float(rgb.min()) >= 0 and float(rgb.max()) <= 1
    assert torch.equal(rgb[0, :, 0, 0], rgb[0, :, 7, 7])  # flat depth, one colour
    assert rgb[1, :, 1, 1].sum() > rgb[1, :, 1, 5].sum()  # near is brighter than far
    assert not rgb[1, :, 0, 0].any()
    assert panel([rgb, rgb]).shape == (3, 2 * 8 + 3 * 2, 2 * 8 + 3 * 2)


def test_pose_warmup_trains_posenet_alone_first(plane_dataset, tmp_path):
    """model.pose_warmup_steps N: the first N optimiser steps change PoseNet only (the depth
    network's weights and batch-norm statistics stay); later steps change both."""
    L.seed_everything(0)
    model = DepthNet(TINY, LossConfig(**MONODEPTH2), pose_warmup_steps=2)
    start = {k: v.clone() for k, v in model.state_dict().items()}

    def changed(prefix: str) -> bool:
        return any(not torch.equal(v, start[k]) for k, v in model.state_dict().items() if k.startswith(prefix))

    trainer(tmp_path, max_steps=2, limit_val_batches=0).fit(model, datamodule=datamodule(plane_dataset))
    assert changed("pose_net.") and not changed("depth_net.")
    model = DepthNet(TINY, LossConfig(**MONODEPTH2), pose_warmup_steps=2)
    model.load_state_dict(start)
    trainer(tmp_path, max_steps=3, limit_val_batches=0).fit(model, datamodule=datamodule(plane_dataset))
    assert changed("pose_net.") and changed("depth_net.")
    with pytest.raises(InputError, match="model.pose_warmup_steps must be >= 0"):
        DepthNet(TINY, pose_warmup_steps=-1)


def test_pose_warmup_that_adapts_norm_moves_statistics_not_weights(plane_dataset, tmp_path):
    """model.warmup_adapts_norm: during the pose warm-up the depth network's batch-norm running
    statistics follow the new images while its parameters stay."""
    L.seed_everything(0)
    model = DepthNet(TINY, LossConfig(**MONODEPTH2), pose_warmup_steps=2, warmup_adapts_norm=True)
    params = {k: v.clone() for k, v in model.depth_net.named_parameters()}
    buffers = {k: v.clone() for k, v in model.depth_net.named_buffers() if k.endswith("running_mean")}
    assert buffers
    trainer(tmp_path, max_steps=2, limit_val_batches=0).fit(model, datamodule=datamodule(plane_dataset))
    assert all(torch.equal(v, params[k]) for k, v in model.depth_net.named_parameters())
    now = dict(model.depth_net.named_buffers())
    assert any(not torch.equal(now[k], v) for k, v in buffers.items())
