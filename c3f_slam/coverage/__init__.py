"""Unseen-surface estimate of a run: how much of the colon wall no frame observed, and where.

From a run's own outputs (registered camera-to-world poses, the fused mesh; no ground truth):
:mod:`.centreline` (the explored segment's centreline, arc length in metres), :mod:`.wall`
(the complete wall as a generalized cylinder r(s, theta), filled where nothing was
reconstructed), :mod:`.visibility` (in view, in the fused depth range, not occluded),
:mod:`.estimate` (shares per segment and overall), :mod:`.render` (unrolled map PNG, the
mesh with the unseen wall painted). Torch-free (NumPy, SciPy, Open3D, matplotlib).
"""

from c3f_slam.config import CoverageConfig
from c3f_slam.coverage.centreline import Centreline, centreline_from_path
from c3f_slam.coverage.estimate import (
    CoverageMap,
    CoverageUnavailable,
    compute_coverage,
    settings_dict,
    settings_from_dict,
)
from c3f_slam.coverage.visibility import ViewSettings
from c3f_slam.coverage.wall import WallModel, fit_wall

__all__ = ["Centreline", "CoverageConfig", "CoverageMap", "CoverageUnavailable", "ViewSettings", "WallModel",
           "centreline_from_path", "compute_coverage", "fit_wall", "settings_dict",
           "settings_from_dict"]
