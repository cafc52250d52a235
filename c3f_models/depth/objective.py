"""DepthNet's self-supervised objective on a frame triplet (docs/design.md, Depth network losses; paper §3.1).

Frames are indexed 0, 1, 2 = (t-1, t, t+1). A pair (i, j) means *target* i reconstructed
from *source* j by inverse warping: the target's depth D_i and the pose T_ji carry i's
pixels into j, where I_j (and D_j) are sampled.

- ``L_ph``: targets t with sources t-1 and t+1, per-pixel minimum, Monodepth2 auto-mask.
- ``L_ph-extra``: pairs S = {(t-1, t), (t-1, t+1), (t+1, t-1), (t+1, t)}: the source frames
  are targets too; per pair, the mean photometric error over the valid pixels (inside the
  source image, not specular in either frame).
- Auto-mask mu, both photometric terms: as in Monodepth2, a pixel where the unwarped source
  is at least as good as the warped one contributes the unwarped (identity) error, a
  constant without gradient, instead of being dropped. Gradients on V_mu are the paper's
  (up to the normaliser |valid| instead of |V_mu|), but emptying V_mu is no trivial optimum:
  with a literal 1/|V_mu| mean a tiny model learnt to predict no motion and drove the loss
  to 0 within 10 steps.
- ``L_dc``: the same pairs, |D_i->j - D~_j| / (D_i->j + D~_j) with D_i->j the target depth
  seen from the source camera and D~_j the source depth interpolated there (SC-SfMLearner).
  Its pixels are the geometrically valid, non-specular ones (no auto-mask: depth consistency
  does not need visible motion).
- Outliers: pixels above the 80th percentile (per image, per pair) of each term's error are
  dropped from that term.
- L = L_ph + lambda_ph_extra * mean_S L_ph-extra + lambda_dc * mean_S L_dc (no smoothness).
  With a warm-up (``lambda_dc_warmup_steps``), training steps minimise the same sum with the
  ramped weight of L_dc instead (``LossTerms.training_loss``).

Poses: PoseNet gives T_10 (t-1 into t) and T_21 (t into t+1) for adjacent frames; the rest
are composed: T_01 = T_10^-1, T_12 = T_21^-1, T_20 = T_21 T_10, T_02 = T_20^-1.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F

from c3f_core.errors import InputError
from c3f_models.depth.losses import (
    automask,
    depth_consistency_error,
    masked_mean,
    min_over_sources,
    percentile_mask,
    photometric_error,
)
from c3f_models.geometry import invert_pose, warp

PH_PAIRS = ((1, 0), (1, 2))  # (target, source) for L_ph: t from t-1 and t+1
EXTRA_PAIRS = ((0, 1), (0, 2), (2, 0), (2, 1))  # S as (i, j) = (target, source)


@dataclass(frozen=True)
class LossConfig:
    """Switches and weights of the objective; the Monodepth2 baseline turns the four extras off.

    Attributes:
        use_automask: Monodepth2 auto-masking in L_ph and L_ph-extra.
        use_extra_photometric: the extra photometric term L_ph-extra over the pairs S.
        use_depth_consistency: the depth-consistency term L_dc over the pairs S.
        use_outlier_mask: drop pixels above ``outlier_percentile`` of each term's error.
        use_specular_mask: exclude specular pixels from the losses.
        lambda_ph_extra: weight of L_ph-extra.
        lambda_dc: weight of L_dc.
        lambda_dc_warmup_steps: training steps over which the weight of L_dc ramps linearly from 0
            to lambda_dc (0 = constant, as the paper; validation and test always use lambda_dc).
        ssim_alpha: SSIM weight in the photometric error (1 - alpha goes to L1).
        outlier_percentile: quantile in (0, 1] above which pixels are outliers.
        lambda_gt_depth: weight of a supervised term on ground-truth depth, mean |log D - log D_gt|
            over frame t's pixels with true depth at every scale (beyond the paper, which is
            self-supervised: 0 = off, the default; > 0 needs training data with depth, e.g. the
            simulator's, and is a deviation to report). Used by the demo (``c3f_demo``) so
            depth is usable within a CPU budget.
        lambda_gt_gradient: weight of a supervised gradient-matching term on ground-truth depth
            (:func:`~c3f_models.depth.losses.log_gradient_matching`, frame t, every scale): the
            depth steps where the true depth steps (fold crests). 0 = off (default); > 0 needs
            training data with depth; a deviation to report, like ``lambda_gt_depth``.
        gt_gradient_edge: the gradient term's edge threshold in true log depth between
            neighbours (0 = every pair of neighbours; 0.05 = only where the truth steps by more
            than 5 %, so that the few fold-crest pixels are not averaged away).
    """

    use_automask: bool = True
    use_extra_photometric: bool = True
    use_depth_consistency: bool = True
    use_outlier_mask: bool = True
    use_specular_mask: bool = True
    lambda_ph_extra: float = 0.1
    lambda_dc: float = 0.1
    lambda_dc_warmup_steps: int = 0
    ssim_alpha: float = 0.85
    outlier_percentile: float = 0.8
    lambda_gt_depth: float = 0.0
    lambda_gt_gradient: float = 0.0
    gt_gradient_edge: float = 0.0

    def __post_init__(self) -> None:
        if not 0 < self.outlier_percentile <= 1:
            raise InputError(f"model.loss.outlier_percentile must be in (0, 1], got {self.outlier_percentile}")
        if self.lambda_dc_warmup_steps < 0:
            raise InputError(f"model.loss.lambda_dc_warmup_steps must be >= 0, got {self.lambda_dc_warmup_steps}")
        for name in ("lambda_gt_depth", "lambda_gt_gradient", "gt_gradient_edge"):
            if getattr(self, name) < 0:
                raise InputError(f"model.loss.{name} must be >= 0, got {getattr(self, name)}")

    @property
    def needs_source_depth(self) -> bool:
        """Whether depth must be predicted for t-1 and t+1 as well."""
        return self.use_extra_photometric or self.use_depth_consistency

    @property
    def warms_up_dc(self) -> bool:
        """Whether the training weight of L_dc ramps up (L_dc on and a warm-up set)."""
        return self.use_depth_consistency and self.lambda_dc_warmup_steps > 0

    def dc_weight(self, step: int) -> float:
        """Weight of L_dc in the training loss at optimiser step ``step``: the linear ramp over
        ``lambda_dc_warmup_steps``, then ``lambda_dc``."""
        n = self.lambda_dc_warmup_steps
        return self.lambda_dc * (1.0 if n <= 0 else min(1.0, step / n))


@dataclass
class LossTerms:
    """The loss and its terms (scalars; None when switched off) plus masks for logging.

    ``loss``: the objective with the configured weights (what is logged, and the validation
    and test loss). ``training_loss``: what a training step minimises, ``loss`` with L_dc
    weighted by the warm-up (:meth:`LossConfig.dc_weight`); ``loss`` itself without a warm-up.
    ``automask``: (B, 1, H, W) bool, the auto-mask mu of frame t at the finest scale: pixels
    where a warped source beat the unwarped ones and that survived the specular and outlier
    masks (the pixels whose L_ph drives depth and pose). ``gt``: the supervised term
    (``LossConfig.lambda_gt_depth``; None when off) and ``gt_gradient`` the supervised
    gradient-matching term (``LossConfig.lambda_gt_gradient``; None when off), unweighted here,
    already weighted into both losses.
    """

    loss: torch.Tensor
    ph: torch.Tensor
    ph_extra: torch.Tensor | None
    dc: torch.Tensor | None
    automask: torch.Tensor
    training_loss: torch.Tensor
    gt: torch.Tensor | None = None
    gt_gradient: torch.Tensor | None = None


def compose_triplet_poses(T_10: torch.Tensor, T_21: torch.Tensor) -> dict[tuple[int, int], torch.Tensor]:
    """All relative poses T_ij (frame j into frame i) of a triplet from the two adjacent ones."""
    T_20 = T_21 @ T_10
    return {
        (1, 0): T_10,
        (2, 1): T_21,
        (0, 1): invert_pose(T_10),
        (1, 2): invert_pose(T_21),
        (2, 0): T_20,
        (0, 2): invert_pose(T_20),
    }


def _stack(frames: list[torch.Tensor], idx: list[int]) -> torch.Tensor:
    """Concatenate frames[idx[0]], frames[idx[1]], ... along the batch dimension."""
    return torch.cat([frames[k] for k in idx], dim=0)


def _split(x: torch.Tensor, n: int) -> torch.Tensor:
    """(n*B, ...) -> (n, B, ...)."""
    return x.view(n, x.shape[0] // n, *x.shape[1:])


class SelfSupervisedLoss:
    """Computes :class:`LossTerms` from images, predicted depths and poses of a triplet."""

    def __init__(self, config: LossConfig) -> None:
        self.cfg = config

    def _warp_pairs(self, pairs, images, specular, depths, poses, K, *, with_source_depth: bool) -> dict:
        """Warp every (target, source) pair at once; per-pair (P, B, 1, H, W) tensors.

        ``pe``/``identity``: photometric error of the warped / unwarped source against the target;
        ``reproj_ok``: the warped sample is inside the source image (and not specular there);
        ``identity_ok``: the unwarped source pixel is not specular; ``target_ok``: the target
        pixel is not specular.
        """
        tgt = [i for i, _ in pairs]
        src = [j for _, j in pairs]
        n = len(pairs)
        src_spec = _stack(specular, src)
        tgt_spec = _stack(specular, tgt)
        source = torch.cat([_stack(images, src), src_spec.to(images[0].dtype)], dim=1)
        T = torch.cat([poses[(j, i)] for i, j in pairs], dim=0)
        source_depth = _stack(depths, src) if with_source_depth else None
        out = warp(source, _stack(depths, tgt), T, K.repeat(n, 1, 1), source_depth)
        target = _stack(images, tgt)
        res = {
            "pe": photometric_error(out.image[:, :3], target, self.cfg.ssim_alpha),
            "identity": photometric_error(_stack(images, src), target, self.cfg.ssim_alpha),
            "reproj_ok": out.valid,
            "identity_ok": torch.ones_like(out.valid),
            "target_ok": torch.ones_like(out.valid),
            "projected": out.projected_depth,
        }
        if self.cfg.use_specular_mask:
            res["reproj_ok"] = out.valid & (out.image[:, 3:] <= 0)
            res["identity_ok"] = ~src_spec
            res["target_ok"] = ~tgt_spec
        if with_source_depth:
            res["sampled"] = out.sampled_depth
        return {k: _split(v, n) for k, v in res.items()}

    def _min_error(self, pe, identity, reproj_ok, identity_ok, target_ok):
        """Per-pixel error to optimise from N candidate sources: inputs (N, B, 1, H, W), target_ok (B, 1, H, W).

        The error is the minimum over the warped sources; with auto-masking, a pixel where an
        unwarped source is at least as good takes that (gradient-free) identity error instead,
        as in Monodepth2, so masked pixels are not simply dropped and an empty mask is no
        trivial optimum. Returns the error, the pixels to average over, and the auto-mask mu
        (pixels where a warped source won), all (B, 1, H, W).
        """
        rep, rep_ok = min_over_sources(pe, reproj_ok)
        keep = rep_ok & target_ok
        if not self.cfg.use_automask:
            return rep, keep, keep
        idn, idn_ok = min_over_sources(identity, identity_ok)
        use_identity = idn_ok & ~(rep_ok & automask(rep, idn))
        err = torch.where(use_identity, idn, rep)
        keep = (rep_ok | idn_ok) & target_ok
        return err, keep, keep & ~use_identity

    def _outliers(self, error: torch.Tensor, keep: torch.Tensor) -> torch.Tensor:
        if not self.cfg.use_outlier_mask:
            return keep
        flat_e, flat_k = error.flatten(0, 1), keep.flatten(0, 1)
        return percentile_mask(flat_e, flat_k, self.cfg.outlier_percentile).view_as(keep)

    def single_scale(
        self,
        images: list[torch.Tensor],
        specular: list[torch.Tensor],
        depths: dict[int, torch.Tensor],
        poses: dict[tuple[int, int], torch.Tensor],
        K: torch.Tensor,
        dc_weight: float | None = None,
    ) -> LossTerms:
        """Terms for one set of full-resolution depths (frame index -> (B, 1, H, W) metres);
        ``dc_weight``: the training weight of L_dc when it differs from ``lambda_dc`` (warm-up)."""
        cfg = self.cfg
        dl = [depths.get(k) for k in range(3)]
        w = self._warp_pairs(PH_PAIRS, images, specular, dl, poses, K, with_source_depth=False)
        err, keep, mu = self._min_error(w["pe"], w["identity"], w["reproj_ok"], w["identity_ok"], w["target_ok"][0])
        keep = self._outliers(err[None], keep[None])[0]
        ph = masked_mean(err, keep)
        ph_extra = dc = None
        if cfg.needs_source_depth:
            w = self._warp_pairs(EXTRA_PAIRS, images, specular, dl, poses, K,
                                 with_source_depth=cfg.use_depth_consistency)
            if cfg.use_extra_photometric:
                one = [w[k].flatten(0, 1)[None] for k in ("pe", "identity", "reproj_ok", "identity_ok")]
                err_x, keep_x, _ = self._min_error(*one, w["target_ok"].flatten(0, 1))
                err_x, keep_x = _split(err_x, len(EXTRA_PAIRS)), _split(keep_x, len(EXTRA_PAIRS))
                keep_x = self._outliers(err_x, keep_x)
                ph_extra = masked_mean(err_x, keep_x, dims=(1, 2, 3, 4)).mean()
            if cfg.use_depth_consistency:
                err_dc = depth_consistency_error(w["projected"], w["sampled"])
                keep_dc = self._outliers(err_dc, w["reproj_ok"] & w["target_ok"])
                dc = masked_mean(err_dc, keep_dc, dims=(1, 2, 3, 4)).mean()
        loss = self._weighted_sum(ph, ph_extra, dc, cfg.lambda_dc)
        training = loss if dc_weight is None or dc is None else self._weighted_sum(ph, ph_extra, dc, dc_weight)
        return LossTerms(loss, ph, ph_extra, dc, mu & keep, training)

    def _weighted_sum(self, ph, ph_extra, dc, dc_weight: float) -> torch.Tensor:
        """L_ph + lambda_ph_extra * L_ph-extra + dc_weight * L_dc (terms that are off are None)."""
        loss = ph
        loss = loss + self.cfg.lambda_ph_extra * ph_extra if ph_extra is not None else loss
        return loss + dc_weight * dc if dc is not None else loss

    def __call__(
        self,
        images: list[torch.Tensor],
        specular: list[torch.Tensor],
        disparities: dict[int, list[torch.Tensor]],
        to_depth,
        poses: dict[tuple[int, int], torch.Tensor],
        K: torch.Tensor,
        *,
        step: int | None = None,
    ) -> LossTerms:
        """Multi-scale objective: each scale's disparity is upsampled (bilinear) to full
        resolution, turned into depth with ``to_depth`` and scored; terms are averaged over scales.

        ``disparities``: frame index -> list of per-scale sigmoid disparities (finest first).
        ``step``: the optimiser step of a training batch, for the warm-up of L_dc (None:
        validation or test, ``training_loss`` is ``loss``).
        """
        ramped = step is not None and self.cfg.warms_up_dc
        dc_weight = self.cfg.dc_weight(step) if ramped else None
        size = images[0].shape[-2:]
        n_scales = len(next(iter(disparities.values())))
        per_scale = []
        for s in range(n_scales):
            depths = {}
            for k, disps in disparities.items():
                d = disps[s]
                if d.shape[-2:] != size:
                    d = F.interpolate(d, size=size, mode="bilinear", align_corners=False)
                depths[k] = to_depth(d)
            per_scale.append(self.single_scale(images, specular, depths, poses, K, dc_weight))

        def mean(name: str) -> torch.Tensor | None:
            vals = [getattr(t, name) for t in per_scale]
            return None if vals[0] is None else torch.stack(vals).mean()

        loss = mean("loss")
        training = mean("training_loss") if ramped else loss
        return LossTerms(loss, mean("ph"), mean("ph_extra"), mean("dc"), per_scale[0].automask, training)
