"""ContraFeat as a LightningModule (docs/design.md, ContraFeat; paper §3.2).

Batches are frame pairs (:class:`datamodules.pairs.ContraFeatDataModule`, or any
:mod:`datamodules.base` batch with depth and poses; frame 0 is paired with every later
frame). Per step: SIFT keypoints on CPU (uint8 images, capped per frame, away from specular
highlights), ground-truth matches from depth + poses
(:func:`c3f_slam.matching.ground_truth_matches`), descriptors sampled from the network's
full-resolution map, InfoNCE with tau = 0.01 over the matches of each pair. With
``loss.dense_points > 0`` (off by default, i.e. the paper's loss), training pairs also carry dense
ground-truth correspondences (pixels on a jittered grid moved with the true depth and poses);
they join the pair's matches in the same InfoNCE, as positives and as negatives of every other
match. Validation and test losses always use the keypoint matches only.

Validation / test: ``{stage}/loss`` (the same InfoNCE) and the precision / recall of
mutual-nearest-neighbour matches for SIFT descriptors (``sift``) and ContraFeat descriptors
(``cdf``), each without and with the keypoint filter (``*_kpf_*``, 3D points from the
ground-truth depth): ``test/cdf_recall``, ``test/cdf_precision``, ``test/cdf_kpf_recall``,
``test/cdf_kpf_precision``, ``test/sift_recall``, ... Counts are summed over all pairs (and
processes) before dividing. Where the precision goes: ``{m}_near_precision`` (a wrong match
within 3 x ``ground_truth.pixel_radius`` of the true position counts as right), ``{m}_near_miss_share``
(near misses / wrong matches) and ``{m}_no_counterpart_share`` (near misses where j had no
keypoint within ``pixel_radius`` at all / wrong matches); see
:mod:`c3f_slam.matching.match_accuracy`. With a TensorBoard logger, validation also writes a few match
images (CDF matches; green = correct, yellow = near miss, red = other wrong).
"""

from __future__ import annotations

import numpy as np
import torch
from lightning.pytorch.loggers import TensorBoardLogger

from c3f_core.errors import InputError
from c3f_core.settings import as_config
from c3f_models.config import OptimConfig
from c3f_models.contrafeat.config import ContraFeatLossConfig, ContraFeatNetworkConfig, MatchEvaluationConfig
from c3f_models.contrafeat.graphs import DescriptorGraph, KeypointDescriptorGraph
from c3f_models.contrafeat.loss import batch_info_nce
from c3f_models.contrafeat.network import ContraFeatNet, sample_descriptors
from c3f_models.contrafeat.pairs import (
    DenseSettings,
    GroundTruthSettings,
    KeypointSettings,
    PairData,
    batch_frames,
    make_pairs,
)
from c3f_models.depth.augment import ColorAugmentConfig, color_augment
from c3f_models.module_base import C3FModule
from c3f_slam.matching import MatchCounts
from c3f_slam.matching.match_accuracy import match_and_evaluate, near_misses
from c3f_slam.matching.visual import draw_matches
from export.graphs import OPSET, GraphSpec

METHODS = ("sift", "sift_kpf", "cdf", "cdf_kpf")

# the defaults of ContraFeat's groups (frozen, so one instance serves every module)
DEFAULT_NETWORK, DEFAULT_LOSS = ContraFeatNetworkConfig(), ContraFeatLossConfig()
DEFAULT_OPTIM = OptimConfig(lr=3e-4, weight_decay=1e-4, milestones=())
DEFAULT_KEYPOINTS, DEFAULT_GROUND_TRUTH = KeypointSettings(), GroundTruthSettings()
DEFAULT_EVALUATION = MatchEvaluationConfig()
DEFAULT_AUGMENT = ColorAugmentConfig()


class ContraFeat(C3FModule):
    """Contrastive dense descriptors for SIFT keypoints.

    Each group is a settings dataclass (or a dict of its fields); in a config they are nested
    under ``model.init_args`` (``loss: {dense_points: 512}``; ``--model.loss.dense_points 512``).

    Args:
        network: the descriptor network (ResNet18 + FPN, c = 128 in the paper; the encoder is chosen by
            name, docs/add_network.md).
        loss: InfoNCE temperature and direction, dense correspondences.
        optim: AdamW and its MultiStepLR schedule (default: lr 3e-4, constant).
        keypoints: SIFT keypoints per frame.
        ground_truth: ground-truth matching radius (pixels) and occlusion test.
        evaluation: keypoint filter, ratio tests and match images of validation and test.
        augment: colour augmentation of the training inputs, drawn for each frame of a pair on its
            own (beyond the paper; off by default): the descriptors must match across a change of
            light or mucosa colour. Keypoints and ground truth come from the original frames.
        init_weights: checkpoint whose weights start ``fit`` (optimiser and epoch not resumed).
    """

    weights_hint = "check model.network"
    zoo_kind = "descriptors"
    checkpoint_prefixes = ("net.",)

    def __init__(
        self,
        network: ContraFeatNetworkConfig = DEFAULT_NETWORK,
        loss: ContraFeatLossConfig = DEFAULT_LOSS,
        optim: OptimConfig = DEFAULT_OPTIM,
        keypoints: KeypointSettings = DEFAULT_KEYPOINTS,
        ground_truth: GroundTruthSettings = DEFAULT_GROUND_TRUTH,
        evaluation: MatchEvaluationConfig = DEFAULT_EVALUATION,
        init_weights: str | None = None,
        augment: ColorAugmentConfig = DEFAULT_AUGMENT,
    ) -> None:
        network = as_config(network, DEFAULT_NETWORK, "model.network")
        loss = as_config(loss, DEFAULT_LOSS, "model.loss")
        keypoints = as_config(keypoints, DEFAULT_KEYPOINTS, "model.keypoints")
        ground_truth = as_config(ground_truth, DEFAULT_GROUND_TRUTH, "model.ground_truth")
        evaluation = as_config(evaluation, DEFAULT_EVALUATION, "model.evaluation")
        self.augment_config = as_config(augment, DEFAULT_AUGMENT, "model.augment")
        super().__init__(as_config(optim, DEFAULT_OPTIM, "model.optim"), init_weights)
        self.save_hyperparameters()
        self.network_config, self.loss_config, self.evaluation_config = network, loss, evaluation
        self.filter_cfg = evaluation.match_filter()
        self.net = ContraFeatNet(network)
        self.kp_settings, self.gt_settings = keypoints, ground_truth
        self.dense_settings = DenseSettings(loss.dense_points, loss.dense_spacing, keypoints.border)
        self._counts: dict[str, MatchCounts] = {}
        self._visuals: list[np.ndarray] = []

    # ------------------------------------------------------------------ inference
    def export_graphs(self) -> list[GraphSpec]:
        """The descriptor graphs: ``descriptors`` (image -> dense unit-length descriptors at the
        input resolution, ``contrafeat.onnx``) and ``descriptors_kp`` (image and (B, N, 2)
        keypoints in input pixels -> (B, N, C) unit descriptors there, ``contrafeat_kp.onnx``)."""
        dim = int(self.net.descriptor_dim)
        return [
            GraphSpec(kind="descriptors", module=DescriptorGraph(self.net), input_names=("image",),
                      output_name="descriptors", output_units="unit L2 norm",
                      output_meaning="dense descriptors, unit length per pixel", file_name="contrafeat.onnx",
                      opset=OPSET, output_channels=dim, sampling="dense"),
            GraphSpec(kind="descriptors", module=KeypointDescriptorGraph(self.net), input_names=("image", "keypoints"),
                      output_name="descriptors", output_units="unit L2 norm",
                      output_meaning="descriptors at the keypoints (bilinear, clamped at the border, re-normalised), "
                                     "unit length per keypoint",
                      file_name="contrafeat_kp.onnx", opset=OPSET, output_channels=dim, name="descriptors_kp",
                      sampling="keypoints"),
        ]

    def forward(self, image: torch.Tensor) -> torch.Tensor:
        """(B, 3, H, W) RGB in [0, 1] -> (B, C, H, W) unit descriptors."""
        return self.net(image)

    @torch.no_grad()
    def describe(self, image: torch.Tensor, keypoints: np.ndarray | torch.Tensor) -> torch.Tensor:
        """(N, C) descriptors of one (3, H, W) image in [0, 1] at (N, 2) pixel coordinates (no gradient)."""
        xy = torch.as_tensor(np.asarray(keypoints, dtype=np.float32), device=self.device)
        return sample_descriptors(self.net(image[None].to(self.device))[0], xy)

    # ------------------------------------------------------------------ shared step
    def _descriptor_maps(self, batch: dict, augment: bool = False) -> torch.Tensor:
        """(B, F, C, H, W) descriptor maps of the batch's frames; with ``augment`` the network sees
        each frame after its own colour change (``model.augment``)."""
        images = batch["image"]
        b, f = images.shape[:2]
        if f < 2:
            raise InputError(f"ContraFeat needs frame pairs (F >= 2), got F = {f}")
        if "depth" not in batch or "pose" not in batch:
            raise InputError("ContraFeat needs ground-truth depth and poses in the batch (depth/ and poses.txt)")
        if augment and self.augment_config.p > 0:
            images = torch.stack([color_augment([images[:, k]], self.augment_config)[0] for k in range(f)], dim=1)
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
        self, batch: dict, sift_descriptors: bool, dense: bool = False, augment: bool = False
    ) -> tuple[torch.Tensor, torch.Tensor, list[PairData], dict]:
        maps = self._descriptor_maps(batch, augment)
        frames = batch_frames(batch)
        use_dense = dense and self.dense_settings.points > 0
        rng = np.random.default_rng(int(torch.randint(0, 2**31 - 1, ()))) if use_dense else None  # follows the seed
        pairs = make_pairs(frames, self.kp_settings, self.gt_settings, sift_descriptors,
                           self.dense_settings if use_dense else None, rng)
        loss, _ = batch_info_nce(self._matched_descriptors(maps, pairs), self.loss_config.tau,
                                 self.loss_config.symmetric)
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
        loss, _, _, stats = self._loss(batch, sift_descriptors=False, dense=True, augment=True)
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
        ev_cfg, radius = self.evaluation_config, self.gt_settings.pixel_radius
        counts = {m: MatchCounts() for m in METHODS}
        details = []
        for p in pairs:
            fi, fj = frames[p.b][p.i], frames[p.b][p.j]
            common = {
                "kp_i": p.kp_i.xy, "kp_j": p.kp_j.xy, "depth_i": fi.depth, "depth_j": fj.depth, "K": fi.K,
                "gt_matches": p.gt, "projection": p.projection, "filter_cfg": self.filter_cfg, "pixel_radius": radius,
            }
            with torch.no_grad():
                xy_i = torch.as_tensor(p.kp_i.xy, dtype=torch.float32, device=maps.device)
                xy_j = torch.as_tensor(p.kp_j.xy, dtype=torch.float32, device=maps.device)
                da = sample_descriptors(maps[p.b, p.i].float(), xy_i)
                db = sample_descriptors(maps[p.b, p.j].float(), xy_j)
            cdf = match_and_evaluate(da.cpu().numpy(), db.cpu().numpy(), metric="cosine", ratio=ev_cfg.cdf_ratio,
                                     **common)
            sift = match_and_evaluate(
                p.kp_i.descriptors, p.kp_j.descriptors, metric="l2", ratio=ev_cfg.sift_ratio, **common
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
        if stage == "val" and batch_idx < self.evaluation_config.num_visualisations and details:
            p, ev = details[0]
            fi, fj = stats["frames"][p.b][p.i], stats["frames"][p.b][p.j]
            scale = max(1, 256 // fi.image.shape[0])
            self._visuals.append(
                draw_matches(fi.image, fj.image, p.kp_i.xy, p.kp_j.xy, ev.matches, correct=ev.correct, scale=scale,
                             near=near_misses(ev.matches, p.kp_j.xy, p.projection, ev.correct,
                                              pixel_radius=self.gt_settings.pixel_radius)[0])
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


__all__ = ["METHODS", "ContraFeat"]
