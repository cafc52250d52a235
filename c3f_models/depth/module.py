"""DepthNet: self-supervised monocular depth for colonoscopy as a LightningModule (docs/design.md, DepthNet).

Batches come from :mod:`datamodules.base` with frame triplets (t-1, t, t+1): ``image``
(B, 3, 3, H, W) in [0, 1], ``specular`` (B, 3, 1, H, W), ``K`` (B, 3, 3), optional ``depth``.
The module predicts depth (metres) for t (and t-1, t+1 when the extra losses need them), the
adjacent poses with PoseNet, and minimises :class:`c3f_models.depth.objective.SelfSupervisedLoss`.
The same code is the Monodepth2 baseline with ``loss.use_extra_photometric``,
``use_depth_consistency``, ``use_outlier_mask`` and ``use_specular_mask`` off
(``configs/depthnet/monodepth2.yaml``).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from lightning.pytorch.loggers import TensorBoardLogger

from c3f_core.errors import InputError
from c3f_core.settings import as_config
from c3f_models.config import OptimConfig
from c3f_models.depth.augment import ColorAugmentConfig, color_augment
from c3f_models.depth.config import DepthEvaluationConfig, DepthNetworkConfig
from c3f_models.depth.graphs import DepthGraph, PoseGraph
from c3f_models.depth.losses import log_depth_l1, log_gradient_matching
from c3f_models.depth.networks import DepthNetwork, PoseNetwork
from c3f_models.depth.objective import LossConfig, LossTerms, SelfSupervisedLoss, compose_triplet_poses
from c3f_models.depth.visual import colorize_depth, mask_to_rgb, panel
from c3f_models.module_base import C3FModule
from c3f_slam.evaluation.depth import METRIC_NAMES, depth_metrics
from export.graphs import OPSET, OPSET_DEFORM, GraphSpec, has_deform_conv

# the defaults of DepthNet's groups (frozen, so one instance serves every module)
DEFAULT_NETWORK, DEFAULT_LOSS, DEFAULT_OPTIM = DepthNetworkConfig(), LossConfig(), OptimConfig()
DEFAULT_EVALUATION, DEFAULT_AUGMENT = DepthEvaluationConfig(), ColorAugmentConfig()


class DepthNet(C3FModule):
    """Self-supervised DepthNet + PoseNet (Monodepth2 architecture, C3Fusion losses).

    Each group is a settings dataclass (or a dict of its fields); in a config they are nested
    under ``model.init_args`` (``loss: {lambda_dc: 0.1}``; ``--model.loss.lambda_dc 0.1``).

    Args:
        network: encoders (by name, docs/add_network.md), DCN, pretrained weights, depth range (metres),
            decoder scales, pose scale.
        loss: switches and weights of the objective (all extras off = Monodepth2), L_dc warm-up.
        optim: AdamW and its MultiStepLR schedule (epochs).
        evaluation: ground-truth range of the metrics, TensorBoard images.
        augment: colour augmentation of the training inputs (off by default; the losses see the originals).
        init_weights: checkpoint whose weights start ``fit`` (optimiser and epoch not resumed;
            for test-time training); ignored when resuming with ``ckpt_path``.
        pose_warmup_steps: the first optimiser steps of ``fit`` train PoseNet alone (the depth
            network frozen; its batch-norm statistics too unless ``warmup_adapts_norm``). For
            test-time training: the pose network fits the new sequence on the given depth
            before depth moves, so the photometric error of wrong poses is not absorbed by the
            depth (0 = off).
        warmup_adapts_norm: during the pose warm-up the depth network's batch-norm layers run in
            training mode: their running statistics follow the new sequence's images (an
            appearance adaptation that needs no gradient and no ground truth) while its weights
            stay. Off: the statistics stay too.
    """

    weights_hint = ("check model.network.encoder_layers, encoder_width, dcn, pose_encoder_layers, "
                    "pose_encoder_width, and encoder, pose_encoder and their options")
    zoo_kind = "depth"
    checkpoint_prefixes = ("depth_net.", "pose_net.")

    def __init__(
        self,
        network: DepthNetworkConfig = DEFAULT_NETWORK,
        loss: LossConfig = DEFAULT_LOSS,
        optim: OptimConfig = DEFAULT_OPTIM,
        evaluation: DepthEvaluationConfig = DEFAULT_EVALUATION,
        init_weights: str | None = None,
        augment: ColorAugmentConfig = DEFAULT_AUGMENT,
        pose_warmup_steps: int = 0,
        warmup_adapts_norm: bool = False,
    ) -> None:
        network = as_config(network, DEFAULT_NETWORK, "model.network")
        loss = as_config(loss, DEFAULT_LOSS, "model.loss")
        optim = as_config(optim, DEFAULT_OPTIM, "model.optim")
        evaluation = as_config(evaluation, DEFAULT_EVALUATION, "model.evaluation")
        augment = as_config(augment, DEFAULT_AUGMENT, "model.augment")
        if pose_warmup_steps < 0:
            raise InputError(f"model.pose_warmup_steps must be >= 0, got {pose_warmup_steps}")
        super().__init__(optim, init_weights)
        self.save_hyperparameters()
        self.pose_warmup_steps, self.warmup_adapts_norm = pose_warmup_steps, warmup_adapts_norm
        self.network_config, self.loss_config, self.evaluation_config = network, loss, evaluation
        self.augment_config = augment
        self.depth_net, self.pose_net = DepthNetwork(network), PoseNetwork(network)
        self.objective = SelfSupervisedLoss(loss)
        self.eval_range = (evaluation.min_depth or network.min_depth, evaluation.max_depth or network.max_depth)

    # ------------------------------------------------------------------ inference
    def forward(self, image: torch.Tensor) -> torch.Tensor:
        """(B, 3, H, W) RGB in [0, 1] -> (B, 1, H, W) depth in metres (finest scale)."""
        return self.depth_net.to_depth(self.depth_net(image)[0])

    def export_graphs(self) -> list[GraphSpec]:
        """The depth graph (image -> depth, metres) and the pose graph (two images -> T_ba)."""
        depth = DepthGraph(self.depth_net)
        return [
            GraphSpec(kind="depth", module=depth, input_names=("image",), output_name="depth", output_units="m",
                      output_meaning="depth along the optical axis (z), metres", file_name="depthnet.onnx",
                      opset=OPSET_DEFORM if has_deform_conv(depth) else OPSET, output_channels=1,
                      depth_range=(self.depth_net.min_depth, self.depth_net.max_depth)),
            GraphSpec(kind="pose", module=PoseGraph(self.pose_net), input_names=("image_a", "image_b"),
                      output_name="T_ba", output_units="m",
                      output_meaning="rigid transform from camera-a to camera-b coordinates (image_a earlier)",
                      file_name="posenet.onnx", opset=OPSET),
        ]

    def predict_step(self, batch, batch_idx: int = 0) -> torch.Tensor:
        """Depth (B, 1, H, W) metres of the centre frame (or of a plain (B, 3, H, W) image batch)."""
        image = batch["image"] if isinstance(batch, dict) else batch
        if image.dim() == 5:
            image = image[:, image.shape[1] // 2]
        return self(image)

    # ------------------------------------------------------------------ training
    def _unpack(self, batch: dict) -> tuple[list[torch.Tensor], list[torch.Tensor], torch.Tensor]:
        image = batch["image"]
        if image.dim() != 5 or image.shape[1] != 3:
            raise InputError(
                "DepthNet needs frame triplets (data.sampling.frame_offsets [-1, 0, 1]); "
                f"got an image batch of shape {tuple(image.shape)}"
            )
        spec = batch.get("specular")
        if spec is None:
            spec = torch.zeros_like(image[:, :, :1], dtype=torch.bool)
        return list(image.unbind(1)), list(spec.bool().unbind(1)), batch["K"]

    def compute_loss(self, batch: dict, step: int | None = None) -> tuple[LossTerms, dict[int, list[torch.Tensor]]]:
        """Predict depths and poses for a triplet batch and score them.

        ``step``: the optimiser step of a training batch (the warm-up of L_dc), None otherwise.
        Returns the loss terms and the disparities (frame index -> per-scale list).
        """
        images, specular, K = self._unpack(batch)
        b = images[0].shape[0]
        seen = color_augment(images, self.augment_config) if step is not None else images  # the networks' inputs
        frames = [1, 0, 2] if self.loss_config.needs_source_depth else [1]
        disps = self.depth_net(torch.cat([seen[k] for k in frames]))
        disparities = {k: [d[n * b : (n + 1) * b].float() for d in disps] for n, k in enumerate(frames)}
        T = self.pose_net(torch.cat([seen[0], seen[1]]), torch.cat([seen[1], seen[2]]))
        # geometry and losses in float32 even under mixed precision (pixel coordinates, SSIM)
        with torch.autocast(images[0].device.type, enabled=False):
            images = [im.float() for im in images]
            poses = compose_triplet_poses(T[:b].float(), T[b:].float())  # T_10 (t-1 -> t), T_21 (t -> t+1)
            terms = self.objective(images, specular, disparities, self.depth_net.to_depth, poses, K.float(), step=step)
            if self.loss_config.lambda_gt_depth > 0 or self.loss_config.lambda_gt_gradient > 0:
                self._add_supervised_term(terms, batch, disparities[1])
        return terms, disparities

    def _add_supervised_term(self, terms: LossTerms, batch: dict, disparities_t: list[torch.Tensor]) -> None:
        """Add ``lambda_gt_depth`` x :func:`log_depth_l1` (``terms.gt``) and ``lambda_gt_gradient``
        x :func:`log_gradient_matching` (``terms.gt_gradient``), each the mean over scales, on
        frame t (in place; the terms are those switched on, unweighted)."""
        cfg = self.loss_config
        if "depth" not in batch:
            raise InputError("model.loss.lambda_gt_depth or lambda_gt_gradient > 0 needs ground-truth depth in every "
                             "training sequence")
        gt = batch["depth"][:, 1].float()
        l1, grad = [], []
        for d in disparities_t:
            if d.shape[-2:] != gt.shape[-2:]:
                d = F.interpolate(d, size=gt.shape[-2:], mode="bilinear", align_corners=False)
            depth = self.depth_net.to_depth(d)
            if cfg.lambda_gt_depth > 0:
                l1.append(log_depth_l1(depth, gt))
            if cfg.lambda_gt_gradient > 0:
                grad.append(log_gradient_matching(depth, gt, edge=cfg.gt_gradient_edge))
        weighted = 0.0
        if l1:
            terms.gt = torch.stack(l1).mean()
            weighted = weighted + cfg.lambda_gt_depth * terms.gt
        if grad:
            terms.gt_gradient = torch.stack(grad).mean()
            weighted = weighted + cfg.lambda_gt_gradient * terms.gt_gradient
        same = terms.training_loss is terms.loss
        terms.loss = terms.loss + weighted
        terms.training_loss = terms.loss if same else terms.training_loss + weighted

    def _log_terms(self, stage: str, terms: LossTerms, batch_size: int) -> None:
        on_step = stage == "train"
        values = {"loss": terms.loss, "ph": terms.ph, "ph_extra": terms.ph_extra, "dc": terms.dc, "gt_depth": terms.gt,
                  "gt_gradient": terms.gt_gradient}
        for name, value in values.items():
            if value is not None:
                self.log(f"{stage}/{name}", value.detach(), on_step=on_step, on_epoch=not on_step,
                         prog_bar=name == "loss", batch_size=batch_size, sync_dist=not on_step)
        self.log(f"{stage}/automask_kept", terms.automask.float().mean(), on_step=on_step, on_epoch=not on_step,
                 batch_size=batch_size, sync_dist=not on_step)

    def _log_depth_spread(self, stage: str, depth: torch.Tensor) -> None:
        """``{stage}/depth_cv``: spatial std / mean of the predicted depth of frame t, averaged
        over the batch. Near 0 means a flat prediction: the network has collapsed (a failure
        mode of self-supervised depth when the photometric signal is weak)."""
        flat = depth.detach().flatten(1).float()
        cv = (flat.std(dim=1) / flat.mean(dim=1).clamp(min=1e-12)).mean()
        on_step = stage == "train"
        self.log(f"{stage}/depth_cv", cv, on_step=on_step, on_epoch=not on_step, batch_size=depth.shape[0],
                 sync_dist=not on_step)

    def on_train_batch_start(self, batch: dict, batch_idx: int) -> None:
        """During the pose warm-up the depth network is frozen: no gradient (the optimiser skips
        it), batch-norm statistics in evaluation mode unless ``warmup_adapts_norm``."""
        if self.pose_warmup_steps > 0:
            frozen = self.global_step < self.pose_warmup_steps
            self.depth_net.requires_grad_(not frozen)
            self.depth_net.train(not frozen or self.warmup_adapts_norm)

    def training_step(self, batch: dict, batch_idx: int) -> torch.Tensor:
        terms, disparities = self.compute_loss(batch, step=self.global_step)
        self._log_terms("train", terms, batch["image"].shape[0])
        self._log_depth_spread("train", self.depth_net.to_depth(disparities[1][0]))
        if self.loss_config.warms_up_dc:
            self.log("train/lambda_dc", self.loss_config.dc_weight(self.global_step), on_step=True, on_epoch=False,
                     batch_size=batch["image"].shape[0])
        return terms.training_loss

    # ------------------------------------------------------------------ evaluation
    def _evaluate(self, stage: str, batch: dict, batch_idx: int) -> dict[str, float] | None:
        terms, disparities = self.compute_loss(batch)
        b = batch["image"].shape[0]
        self._log_terms(stage, terms, b)
        pred = self.depth_net.to_depth(disparities[1][0])
        self._log_depth_spread(stage, pred)
        metrics = None
        if "depth" in batch:
            gt = batch["depth"][:, 1]
            metrics = depth_metrics(pred, gt, min_depth=self.eval_range[0], max_depth=self.eval_range[1])
            if metrics["n_images"] > 0:
                for name in METRIC_NAMES:
                    self.log(f"{stage}/{name}", metrics[name], on_epoch=True, batch_size=metrics["n_images"],
                             sync_dist=True)
                # metres per unit of prediction (mean over batches of the batch median)
                self.log(f"{stage}/gt_to_pred_scale", metrics["scale"], on_epoch=True,
                         batch_size=metrics["n_images"], sync_dist=True)
        if stage == "val" and batch_idx == 0:
            self._log_images(batch, pred, terms)
        return metrics

    def validation_step(self, batch: dict, batch_idx: int) -> None:
        self._evaluate("val", batch, batch_idx)

    def test_step(self, batch: dict, batch_idx: int) -> None:
        self._evaluate("test", batch, batch_idx)

    def _log_images(self, batch: dict, pred: torch.Tensor, terms: LossTerms) -> None:
        """Input, predicted depth, ground truth (if any), kept pixels (auto-mask) and specular mask."""
        n = self.evaluation_config.log_images
        loggers = [lg for lg in self.loggers if isinstance(lg, TensorBoardLogger)]
        if n <= 0 or not loggers or self.trainer.sanity_checking or self.global_rank != 0:
            return
        columns = [batch["image"][:n, 1], colorize_depth(pred[:n])]
        if "depth" in batch:
            columns.append(colorize_depth(batch["depth"][:n, 1]))
        columns.append(mask_to_rgb(terms.automask[:n]))
        columns.append(mask_to_rgb(batch["specular"][:n, 1].bool()) if "specular" in batch
                       else torch.zeros_like(columns[0]))
        grid = panel(columns)
        title = "input | depth | " + ("gt depth | " if "depth" in batch else "") + "kept (auto-mask) | specular"
        for lg in loggers:
            lg.experiment.add_image("val/samples", grid, self.global_step, dataformats="CHW")
            lg.experiment.add_text("val/samples_columns", title, self.global_step)
