"""ContraFeat as a LightningModule (SPEC §3, paper §3.2).

Batches are frame pairs (:class:`c3f_models.contrafeat.data.ContraFeatDataModule`, or any
:mod:`datamodules.base` batch with depth and poses; frame 0 is paired with every later
frame). Per step: SIFT keypoints on CPU (uint8 images, capped per frame, away from specular
highlights), ground-truth matches from depth + poses
(:func:`c3f_slam.matching.ground_truth_matches`), descriptors sampled from the network's
full-resolution map, InfoNCE with tau = 0.01 over the matches of each pair. With
``dense_points > 0`` (off by default, i.e. the paper's loss), training pairs also carry dense
ground-truth correspondences (pixels on a jittered grid moved with the true depth and poses);
they join the pair's matches in the same InfoNCE, as positives and as negatives of every other
match. Validation and test losses always use the keypoint matches only.

Validation / test: ``{stage}/loss`` (the same InfoNCE) and the precision / recall of
mutual-nearest-neighbour matches for SIFT descriptors (``sift``) and ContraFeat descriptors
(``cdf``), each without and with the keypoint filter (``*_kpf_*``, 3D points from the
ground-truth depth): ``test/cdf_recall``, ``test/cdf_precision``, ``test/cdf_kpf_recall``,
``test/cdf_kpf_precision``, ``test/sift_recall``, ... Counts are summed over all pairs (and
processes) before dividing. Where the precision goes: ``{m}_near_precision`` (a wrong match
within 3 x ``pixel_radius`` of the true position counts as right), ``{m}_near_miss_share``
(near misses / wrong matches) and ``{m}_no_counterpart_share`` (near misses where j had no
keypoint within ``pixel_radius`` at all / wrong matches); see
:mod:`c3f_slam.matching.match_accuracy`. With a TensorBoard logger, validation also writes a few match
images (CDF matches; green = correct, yellow = near miss, red = other wrong).
"""

from __future__ import annotations


import lightning as L
import numpy as np
import torch
from lightning.pytorch.loggers import TensorBoardLogger

from c3f_models.contrafeat.loss import TAU, batch_info_nce
from c3f_models.contrafeat.network import ContraFeatNet, sample_descriptors
from c3f_models.contrafeat.pairs import (
    DenseSettings,
    GroundTruthSettings,
    KeypointSettings,
    PairData,
    batch_frames,
    make_pairs,
)
from c3f_slam.errors import InputError
from c3f_slam.matching import MatchCounts, MatchFilterConfig
from c3f_slam.matching.match_accuracy import match_and_evaluate, near_misses
from c3f_slam.matching.visual import draw_matches

METHODS = ("sift", "sift_kpf", "cdf", "cdf_kpf")


class ContraFeat(L.LightningModule):
    """Contrastive dense descriptors for SIFT keypoints.

    Args:
        backbone_layers, descriptor_dim, fpn_channels, stem_channels, head_channels, pretrained_path:
            the network (:class:`c3f_models.contrafeat.network.ContraFeatNet`); the paper's
            is ResNet18, c = 128; ``pretrained_path`` is a local torchvision ResNet state dict
            (ImageNet) or a DepthNet checkpoint without DCN (its depth encoder).
        lr, weight_decay: AdamW (betas 0.9, 0.999).
        lr_milestones: epochs at which the learning rate is halved (empty = constant).
        tau: InfoNCE temperature (paper: 0.01).
        symmetric_loss: average the i->j and j->i InfoNCE directions.
        max_keypoints: SIFT keypoints kept per frame (strongest by response).
        sift_contrast_threshold: OpenCV SIFT contrast threshold (lower = more keypoints).
        keypoint_border: drop keypoints this close (pixels) to the border.
        mask_specular: no keypoints on specular highlights.
        pixel_radius: ground-truth and correctness radius, pixels.
        depth_tolerance: relative depth agreement for visibility (occlusion test).
        cdf_ratio, sift_ratio: optional ratio tests of the mutual-NN matching (evaluation).
        dense_points: dense ground-truth correspondences sampled per training pair and added
            to its InfoNCE (0 = keypoint matches only, the paper's loss).
        dense_spacing: grid cell of the dense samples, pixels (samples >= spacing / 2 apart).
        filter_preset: ``colon`` or ``room`` keypoint-filter thresholds
            (:class:`c3f_slam.matching.MatchFilterConfig`); ``filter_overrides`` changes fields.
        num_visualisations: validation batches that log a match image (TensorBoard only).
    """

    def __init__(
        self,
        backbone_layers: int = 18,
        descriptor_dim: int = 128,
        fpn_channels: int = 128,
        stem_channels: int = 32,
        head_channels: int | None = None,
        pretrained_path: str | None = None,
        lr: float = 3e-4,
        weight_decay: float = 1e-4,
        lr_milestones: list[int] = [],  # noqa: B006 (jsonargparse needs a literal default)
        tau: float = TAU,
        symmetric_loss: bool = True,
        max_keypoints: int = 1024,
        sift_contrast_threshold: float = 0.04,
        keypoint_border: int = 2,
        mask_specular: bool = True,
        pixel_radius: float = 2.0,
        depth_tolerance: float = 0.05,
        cdf_ratio: float | None = None,
        sift_ratio: float | None = None,
        dense_points: int = 0,
        dense_spacing: int = 4,
        filter_preset: str = "colon",
        filter_overrides: dict | None = None,
        num_visualisations: int = 4,
    ) -> None:
        super().__init__()
        self.save_hyperparameters()
        if tau <= 0:
            raise InputError(f"model.tau must be positive, got {tau}")
        if max_keypoints < 2:
            raise InputError(f"model.max_keypoints must be >= 2, got {max_keypoints}")
        if pixel_radius <= 0 or depth_tolerance <= 0:
            raise InputError("model.pixel_radius and model.depth_tolerance must be positive")
        if dense_points < 0 or dense_spacing < 1:
            raise InputError(f"model.dense_points must be >= 0 and model.dense_spacing >= 1, got {dense_points}, "
                             f"{dense_spacing}")
        try:
            self.filter_cfg = MatchFilterConfig.preset(filter_preset, **(filter_overrides or {}))
        except TypeError as exc:
            raise InputError(f"model.filter_overrides: {exc}") from None
        self.net = ContraFeatNet(
            backbone_layers, descriptor_dim, fpn_channels, stem_channels, pretrained_path, head_channels
        )
        self.kp_settings = KeypointSettings(max_keypoints, sift_contrast_threshold, keypoint_border, mask_specular)
        self.gt_settings = GroundTruthSettings(pixel_radius, depth_tolerance)
        self.dense_settings = DenseSettings(dense_points, dense_spacing, keypoint_border)
        self._counts: dict[str, MatchCounts] = {}
        self._visuals: list[np.ndarray] = []

    # ------------------------------------------------------------------ inference
    def forward(self, image: torch.Tensor) -> torch.Tensor:
        """(B, 3, H, W) RGB in [0, 1] -> (B, C, H, W) unit descriptors."""
        return self.net(image)

    @torch.no_grad()
    def describe(self, image: torch.Tensor, keypoints: np.ndarray | torch.Tensor) -> torch.Tensor:
        """(N, C) descriptors of one (3, H, W) image in [0, 1] at (N, 2) pixel coordinates (no gradient)."""
        xy = torch.as_tensor(np.asarray(keypoints, dtype=np.float32), device=self.device)
        return sample_descriptors(self.net(image[None].to(self.device))[0], xy)

    # ------------------------------------------------------------------ shared step
    def _descriptor_maps(self, batch: dict) -> torch.Tensor:
        images = batch["image"]
        b, f = images.shape[:2]
        if f < 2:
            raise InputError(f"ContraFeat needs frame pairs (F >= 2), got F = {f}")
        if "depth" not in batch or "pose" not in batch:
            raise InputError("ContraFeat needs ground-truth depth and poses in the batch (depth/ and poses.txt)")
        maps = self.net(images.flatten(0, 1))
        return maps.view(b, f, *maps.shape[1:])

    def _matched_descriptors(
        self, maps: torch.Tensor, pairs: list[PairData]
    ) -> list[tuple[torch.Tensor, torch.Tensor]]:
        """Descriptors of each pair's matches (keypoint matches, then its dense correspondences if any)."""
        out = []
        for p in pairs:
            xy_a, xy_b = p.kp_i.xy[p.gt[:, 0]], p.kp_j.xy[p.gt[:, 1]]
            if p.dense is not None:
                xy_a, xy_b = np.concatenate([xy_a, p.dense[0]]), np.concatenate([xy_b, p.dense[1]])
            xy_a = torch.as_tensor(xy_a, dtype=torch.float32, device=maps.device)
            xy_b = torch.as_tensor(xy_b, dtype=torch.float32, device=maps.device)
            out.append((sample_descriptors(maps[p.b, p.i], xy_a), sample_descriptors(maps[p.b, p.j], xy_b)))
        return out

    def _loss(
        self, batch: dict, sift_descriptors: bool, dense: bool = False
    ) -> tuple[torch.Tensor, torch.Tensor, list[PairData], dict]:
        maps = self._descriptor_maps(batch)
        frames = batch_frames(batch)
        use_dense = dense and self.dense_settings.points > 0
        rng = np.random.default_rng(int(torch.randint(0, 2**31 - 1, ()))) if use_dense else None  # follows the seed
        pairs = make_pairs(frames, self.kp_settings, self.gt_settings, sift_descriptors,
                           self.dense_settings if use_dense else None, rng)
        loss, _ = batch_info_nce(self._matched_descriptors(maps, pairs), self.hparams.tau, self.hparams.symmetric_loss)
        if loss is None:  # no pair with two matches: a zero loss keeps every process in step
            loss = maps.sum() * 0.0
        stats = {
            # keypoint matches per pair (pairs with fewer than two carry no loss and count as 0)
            "matches": sum(len(p.gt) for p in pairs if len(p.gt) >= 2) / max(len(pairs), 1),
            "dense": float(np.mean([len(p.dense[0]) for p in pairs if p.dense is not None] or [0.0])),
            "keypoints": float(np.mean([len(p.kp_i) for p in pairs])) if pairs else 0.0,
        }
        return loss, maps, pairs, {"frames": frames, **stats}

    # ------------------------------------------------------------------ training
    def training_step(self, batch: dict, batch_idx: int) -> torch.Tensor:
        loss, _, _, stats = self._loss(batch, sift_descriptors=False, dense=True)
        bs = batch["image"].shape[0]
        self.log("train/loss", loss, prog_bar=True, batch_size=bs)
        self.log("train/matches", stats["matches"], batch_size=bs)
        if self.dense_settings.points > 0:
            self.log("train/dense_matches", stats["dense"], batch_size=bs)
        self.log("train/keypoints", stats["keypoints"], batch_size=bs)
        return loss

    # ------------------------------------------------------------------ evaluation
    def evaluate_pairs(
        self, maps: torch.Tensor, frames: list, pairs: list[PairData]
    ) -> tuple[dict[str, MatchCounts], list]:
        """Match counts of SIFT and ContraFeat descriptors (without / with kpf) over the pairs."""
        hp = self.hparams
        counts = {m: MatchCounts() for m in METHODS}
        details = []
        for p in pairs:
            fi, fj = frames[p.b][p.i], frames[p.b][p.j]
            common = dict(
                kp_i=p.kp_i.xy, kp_j=p.kp_j.xy, depth_i=fi.depth, depth_j=fj.depth, K=fi.K,
                gt_matches=p.gt, projection=p.projection, filter_cfg=self.filter_cfg, pixel_radius=hp.pixel_radius,
            )
            with torch.no_grad():
                xy_i = torch.as_tensor(p.kp_i.xy, dtype=torch.float32, device=maps.device)
                xy_j = torch.as_tensor(p.kp_j.xy, dtype=torch.float32, device=maps.device)
                da = sample_descriptors(maps[p.b, p.i].float(), xy_i)
                db = sample_descriptors(maps[p.b, p.j].float(), xy_j)
            cdf = match_and_evaluate(da.cpu().numpy(), db.cpu().numpy(), metric="cosine", ratio=hp.cdf_ratio, **common)
            sift = match_and_evaluate(
                p.kp_i.descriptors, p.kp_j.descriptors, metric="l2", ratio=hp.sift_ratio, **common
            )
            for name, ev in (("cdf", cdf), ("sift", sift)):
                counts[name] = counts[name] + ev.counts
                counts[f"{name}_kpf"] = counts[f"{name}_kpf"] + ev.kpf_counts
            details.append((p, cdf))
        return counts, details

    def _eval_step(self, batch: dict, batch_idx: int, stage: str) -> None:
        loss, maps, pairs, stats = self._loss(batch, sift_descriptors=True)
        bs = batch["image"].shape[0]
        self.log(f"{stage}/loss", loss, batch_size=bs, sync_dist=True, prog_bar=stage == "val")
        self.log(f"{stage}/gt_matches", float(stats["matches"]), batch_size=bs, sync_dist=True)
        counts, details = self.evaluate_pairs(maps.detach(), stats["frames"], pairs)
        for k, c in counts.items():
            self._counts[k] = self._counts.get(k, MatchCounts()) + c
        if stage == "val" and batch_idx < self.hparams.num_visualisations and details:
            p, ev = details[0]
            fi, fj = stats["frames"][p.b][p.i], stats["frames"][p.b][p.j]
            scale = max(1, 256 // fi.image.shape[0])
            self._visuals.append(
                draw_matches(fi.image, fj.image, p.kp_i.xy, p.kp_j.xy, ev.matches, ev.correct, scale=scale,
                             near=near_misses(ev.matches, p.kp_j.xy, p.projection, ev.correct,
                                              self.hparams.pixel_radius)[0])
            )

    def _eval_epoch_end(self, stage: str) -> None:
        if not self._counts:
            return
        table = torch.tensor(np.stack([self._counts.get(m, MatchCounts()).to_array() for m in METHODS]),
                             dtype=torch.float64, device=self.device)
        table = self.trainer.strategy.reduce(table, reduce_op="sum")
        for m, row in zip(METHODS, table.cpu().numpy()):
            c = MatchCounts.from_array(row)
            self.log(f"{stage}/{m}_recall", c.recall, sync_dist=False)
            self.log(f"{stage}/{m}_precision", c.precision, sync_dist=False)
            # where precision goes (c3f_slam.matching.match_accuracy): near misses vs gross errors
            for name in ("near_precision", "near_miss_share", "no_counterpart_share"):
                self.log(f"{stage}/{m}_{name}", getattr(c, name), sync_dist=False)
            if m.endswith("_kpf"):
                self.log(f"{stage}/{m}_accept_rate", c.accepted_pairs / max(c.pairs, 1), sync_dist=False)
        self._counts = {}
        visuals, self._visuals = self._visuals, []
        if stage == "val" and isinstance(self.logger, TensorBoardLogger) and visuals:
            for k, img in enumerate(visuals):
                self.logger.experiment.add_image(f"val/matches_{k}", img, self.global_step, dataformats="HWC")

    def on_validation_epoch_start(self) -> None:
        self._counts, self._visuals = {}, []

    def on_test_epoch_start(self) -> None:
        self._counts, self._visuals = {}, []

    def validation_step(self, batch: dict, batch_idx: int) -> None:
        self._eval_step(batch, batch_idx, "val")

    def test_step(self, batch: dict, batch_idx: int) -> None:
        self._eval_step(batch, batch_idx, "test")

    def on_validation_epoch_end(self) -> None:
        self._eval_epoch_end("val")

    def on_test_epoch_end(self) -> None:
        self._eval_epoch_end("test")

    # ------------------------------------------------------------------ optimiser
    def configure_optimizers(self):
        opt = torch.optim.AdamW(self.parameters(), lr=self.hparams.lr, betas=(0.9, 0.999),
                                weight_decay=self.hparams.weight_decay)
        if not self.hparams.lr_milestones:
            return opt
        sched = torch.optim.lr_scheduler.MultiStepLR(opt, milestones=list(self.hparams.lr_milestones), gamma=0.5)
        return {"optimizer": opt, "lr_scheduler": {"scheduler": sched, "interval": "epoch"}}


__all__ = ["ContraFeat", "METHODS"]
