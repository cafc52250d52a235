"""ContraFeat (paper §3.2): dense contrastive descriptors for SIFT keypoints.

- :mod:`.network`: FPN on a ResNet18 bottom-up stream, full-resolution 128-d unit descriptors;
- :mod:`.loss`: InfoNCE over the ground-truth matches of a frame pair (tau = 0.01);
- :mod:`.data`: frame pairs at several frame gaps (``ContraFeatDataModule``);
- :mod:`.pairs`: per-pair keypoints and ground truth (NumPy, shared with the benchmark);
- the LightningModule is :class:`c3f_models.contrafeat.module.ContraFeat`.
"""

from c3f_models.contrafeat.loss import info_nce
from c3f_models.contrafeat.network import ContraFeatNet, sample_descriptors

__all__ = ["ContraFeatNet", "info_nce", "sample_descriptors"]
