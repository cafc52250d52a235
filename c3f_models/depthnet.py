"""DepthNet: self-supervised monocular depth for colonoscopy as a LightningModule (SPEC §2).

Batches come from :mod:`datamodules.base` with frame triplets (t-1, t, t+1): ``image``
(B, 3, 3, H, W) in [0, 1], ``specular`` (B, 3, 1, H, W), ``K`` (B, 3, 3), optional ``depth``.
The module predicts depth (metres) for t (and t-1, t+1 when the extra losses need them), the
adjacent poses with PoseNet, and minimises :class:`c3f_models.depth.objective.SelfSupervisedLoss`.
The same code is the Monodepth2 baseline with ``use_extra_photometric``,
``use_depth_consistency``, ``use_outlier_mask`` and ``use_specular_mask`` off.
"""

from __future__ import annotations

import re
import zipfile
from collections.abc import Sequence
from pathlib import Path

import lightning as L
import torch
from lightning.pytorch.loggers import TensorBoardLogger

from c3f_models.depth.networks import DepthNetwork, PoseNetwork
from c3f_models.depth.objective import LossConfig, LossTerms, SelfSupervisedLoss, compose_triplet_poses
from c3f_models.depth.visual import colorize_depth, mask_to_rgb, panel
from c3f_models.metrics import METRIC_NAMES, depth_metrics
from c3f_slam.errors import InputError


def read_checkpoint_weights(path: str | Path, option: str = "model.init_weights") -> dict[str, torch.Tensor]:
    """Model weights from a Lightning checkpoint (``state_dict`` key) or a plain state dict file.

    Only the safe unpickler reads it (``torch.load(weights_only=True)``): tensors, numbers,
    strings and containers. A file that needs more (pickled objects, possibly code) is refused
    with an InputError; nothing in it runs.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{option}: file not found: {path}")
    if not zipfile.is_zipfile(path):  # torch.save writes a zip archive
        raise InputError(f"{option}: {path} is not a torch checkpoint")
    try:
        ckpt = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:
        found = re.search(r"Unsupported global: GLOBAL (\S+)", str(exc))
        what = f" (it pickles {found.group(1)})" if found else f" ({type(exc).__name__})"
        raise InputError(f"{option}: {path} needs more than the safe loader (weights_only=True) reads{what}; "
                         "refused, nothing in it ran") from None
    state = ckpt.get("state_dict", ckpt) if isinstance(ckpt, dict) else None
    if not isinstance(state, dict) or not state or not all(isinstance(v, torch.Tensor) for v in state.values()):
        raise InputError(f"{option}: {path} holds no model weights")
    return state


def load_weights(
    module: torch.nn.Module, state: dict[str, torch.Tensor], path: str | Path, option: str,
    what: str = "the model", hint: str = "",
) -> None:
    """Load ``state`` into ``module`` strictly; InputError naming ``option`` and ``path`` with
    the numbers of missing, unexpected and wrong-shaped keys when it does not fit."""
    own = module.state_dict()
    missing = [k for k in own if k not in state]
    unexpected = [k for k in state if k not in own]
    wrong = [k for k in own if k in state and state[k].shape != own[k].shape]
    if missing or unexpected or wrong:
        example = (missing or unexpected or wrong)[0]
        raise InputError(
            f"{option}: {path} does not fit {what} ({len(missing)} missing, {len(unexpected)} unexpected, "
            f"{len(wrong)} wrong-shaped keys, e.g. {example})" + (f"; {hint}" if hint else "")
        )
    module.load_state_dict(state)


class DepthNet(L.LightningModule):
    """Self-supervised DepthNet + PoseNet (Monodepth2 architecture, C3Fusion losses).

    Args:
        encoder_layers: depth encoder ResNet depth (18 for CPU, 50 in the paper).
        dcn: deformable convolutions in the depth encoder's conv3-conv5.
        pose_encoder_layers: PoseNet ResNet depth (18 in the paper).
        pretrained_path, pose_pretrained_path: local torchvision ResNet state dicts (ImageNet)
            for the depth / pose encoder; None trains from scratch.
        pose_translation_scale: metres per unit of PoseNet's raw translation output.
            Monodepth2 uses 0.01 with depths starting near 0.2 m; here depths start near
            2 * min_depth = 2 mm, and 0.001 keeps the first warps' pixel motion in the same
            range (with 0.01 a tiny model often starts with every warp worse than no motion).
        min_depth, max_depth: metres; the sigmoid disparity maps to this depth range.
        num_scales: decoder scales used by the loss (1-4, Monodepth2 uses 4).
        use_automask, use_extra_photometric, use_depth_consistency, use_outlier_mask,
            use_specular_mask: loss switches (all True = C3Fusion; the last four False =
            Monodepth2 without its smoothness term).
        lambda_ph_extra, lambda_dc: weights of L_ph-extra and L_dc.
        lambda_dc_warmup_steps: training steps over which the weight of L_dc ramps linearly
            from 0 to ``lambda_dc`` (0 = constant from the start, as the paper). Not in the
            paper: a guard for training from scratch, where L_dc pulls the depth flat while
            PoseNet is still far off (benchmarks/results/depthnet_diagnosis.md). Validation
            and test losses always use ``lambda_dc``.
        ssim_alpha: SSIM weight in the photometric error.
        outlier_percentile: quantile above which pixels are outliers (0.8).
        lr, weight_decay: AdamW (betas 0.9, 0.999).
        milestones, gamma: MultiStepLR (epochs, factor).
        init_weights: checkpoint whose weights initialise the model at the start of ``fit``
            (optimiser and epoch not resumed; for test-time training). Ignored when a run is
            resumed with ``ckpt_path`` or the module comes from a checkpoint.
        eval_min_depth, eval_max_depth: ground-truth range (metres) for the metrics
            (default: min_depth, max_depth).
        log_images: samples shown in TensorBoard per validation epoch (0 = none).
    """

    def __init__(
        self,
        encoder_layers: int = 18,
        dcn: bool = False,
        pose_encoder_layers: int = 18,
        pretrained_path: str | None = None,
        pose_pretrained_path: str | None = None,
        pose_translation_scale: float = 1e-3,
        min_depth: float = 1e-3,
        max_depth: float = 0.3,
        num_scales: int = 4,
        use_automask: bool = True,
        use_extra_photometric: bool = True,
        use_depth_consistency: bool = True,
        use_outlier_mask: bool = True,
        use_specular_mask: bool = True,
        lambda_ph_extra: float = 0.1,
        lambda_dc: float = 0.1,
        lambda_dc_warmup_steps: int = 0,
        ssim_alpha: float = 0.85,
        outlier_percentile: float = 0.8,
        lr: float = 1e-4,
        weight_decay: float = 1e-2,
        milestones: Sequence[int] = (16, 24, 32),
        gamma: float = 0.5,
        init_weights: str | None = None,
        eval_min_depth: float | None = None,
        eval_max_depth: float | None = None,
        log_images: int = 4,
    ) -> None:
        super().__init__()
        if not 0 < min_depth < max_depth:
            raise InputError(f"model.min_depth/max_depth: need 0 < min_depth < max_depth, got {min_depth}, {max_depth}")
        if not 1 <= num_scales <= 4:
            raise InputError(f"model.num_scales must be 1..4, got {num_scales}")
        if not 0 < outlier_percentile <= 1:
            raise InputError(f"model.outlier_percentile must be in (0, 1], got {outlier_percentile}")
        if lambda_dc_warmup_steps < 0:
            raise InputError(f"model.lambda_dc_warmup_steps must be >= 0, got {lambda_dc_warmup_steps}")
        self.save_hyperparameters()
        self.depth_net = DepthNetwork(encoder_layers, dcn, num_scales, min_depth, max_depth, pretrained_path)
        self.pose_net = PoseNetwork(pose_encoder_layers, pose_pretrained_path, pose_translation_scale)
        self.loss_config = LossConfig(
            use_automask=use_automask,
            use_extra_photometric=use_extra_photometric,
            use_depth_consistency=use_depth_consistency,
            use_outlier_mask=use_outlier_mask,
            use_specular_mask=use_specular_mask,
            lambda_ph_extra=lambda_ph_extra,
            lambda_dc=lambda_dc,
            alpha=ssim_alpha,
            outlier_percentile=outlier_percentile,
        )
        self.objective = SelfSupervisedLoss(self.loss_config)
        self.eval_range = (eval_min_depth or min_depth, eval_max_depth or max_depth)
        self._init_weights_done = False

    # ------------------------------------------------------------------ inference
    def forward(self, image: torch.Tensor) -> torch.Tensor:
        """(B, 3, H, W) RGB in [0, 1] -> (B, 1, H, W) depth in metres (finest scale)."""
        return self.depth_net.to_depth(self.depth_net(image)[0])

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
                "DepthNet needs frame triplets (data.frame_offsets [-1, 0, 1]); "
                f"got an image batch of shape {tuple(image.shape)}"
            )
        spec = batch.get("specular")
        if spec is None:
            spec = torch.zeros_like(image[:, :, :1], dtype=torch.bool)
        return list(image.unbind(1)), list(spec.bool().unbind(1)), batch["K"]

    def compute_loss(self, batch: dict) -> tuple[LossTerms, dict[int, list[torch.Tensor]]]:
        """Predict depths and poses for a triplet batch and score them.

        Returns the loss terms and the disparities (frame index -> per-scale list).
        """
        images, specular, K = self._unpack(batch)
        b = images[0].shape[0]
        frames = [1, 0, 2] if self.loss_config.needs_source_depth else [1]
        disps = self.depth_net(torch.cat([images[k] for k in frames]))
        disparities = {k: [d[n * b : (n + 1) * b].float() for d in disps] for n, k in enumerate(frames)}
        T = self.pose_net(torch.cat([images[0], images[1]]), torch.cat([images[1], images[2]]))
        # geometry and losses in float32 even under mixed precision (pixel coordinates, SSIM)
        with torch.autocast(images[0].device.type, enabled=False):
            images = [im.float() for im in images]
            poses = compose_triplet_poses(T[:b].float(), T[b:].float())  # T_10 (t-1 -> t), T_21 (t -> t+1)
            terms = self.objective(images, specular, disparities, self.depth_net.to_depth, poses, K.float())
        return terms, disparities

    def _log_terms(self, stage: str, terms: LossTerms, batch_size: int) -> None:
        on_step = stage == "train"
        values = {"loss": terms.loss, "ph": terms.ph, "ph_extra": terms.ph_extra, "dc": terms.dc}
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

    def dc_weight(self, step: int) -> float:
        """Weight of L_dc in the training loss at optimiser step ``step`` (the warm-up ramp of
        ``lambda_dc_warmup_steps``, then ``lambda_dc``)."""
        n = self.hparams.lambda_dc_warmup_steps
        return self.loss_config.lambda_dc * (1.0 if n <= 0 else min(1.0, step / n))

    def training_step(self, batch: dict, batch_idx: int) -> torch.Tensor:
        terms, disparities = self.compute_loss(batch)
        self._log_terms("train", terms, batch["image"].shape[0])
        self._log_depth_spread("train", self.depth_net.to_depth(disparities[1][0]))
        loss = terms.loss
        if terms.dc is not None and self.hparams.lambda_dc_warmup_steps > 0:
            w = self.dc_weight(self.global_step)
            # the objective added lambda_dc * L_dc (mean over scales, linear): swap in w
            loss = loss - (self.loss_config.lambda_dc - w) * terms.dc
            self.log("train/lambda_dc", w, on_step=True, on_epoch=False, batch_size=batch["image"].shape[0])
        return loss

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
        n = self.hparams.log_images
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

    # ------------------------------------------------------------------ optimiser and init
    def configure_optimizers(self):
        hp = self.hparams
        opt = torch.optim.AdamW(self.parameters(), lr=hp.lr, betas=(0.9, 0.999), weight_decay=hp.weight_decay)
        sched = torch.optim.lr_scheduler.MultiStepLR(opt, milestones=list(hp.milestones), gamma=hp.gamma)
        return {"optimizer": opt, "lr_scheduler": {"scheduler": sched, "interval": "epoch"}}

    def load_init_weights(self, path: str | Path) -> None:
        """Copy model weights from a checkpoint (strict); InputError if the file or keys do not fit."""
        load_weights(self, read_checkpoint_weights(path), path, "model.init_weights", "this DepthNet",
                     "check encoder_layers, dcn and pose_encoder_layers")
        self._init_weights_done = True

    def setup(self, stage: str) -> None:
        # Runs before Lightning restores a ``ckpt_path``, so a resumed run keeps its own weights.
        if stage == "fit" and self.hparams.init_weights and not self._init_weights_done:
            self.load_init_weights(self.hparams.init_weights)

    def on_load_checkpoint(self, checkpoint: dict) -> None:
        self._init_weights_done = True
