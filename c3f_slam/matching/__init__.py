"""Keypoints, descriptor matching, ground-truth matches and the BundleFusion match filters.

NumPy / OpenCV / SciPy only (no torch): ContraFeat training and evaluation
(:mod:`c3f_models.contrafeat`) and the SLAM runtime share this code.

Conventions (as in :mod:`c3f_slam.geometry`): keypoints are (N, 2) float pixel coordinates
(u, v) with integer values at pixel centres; depth is z in metres (0 = none); poses are
camera-to-world; ``T_ij`` maps frame-j coordinates into frame i (p_i = T_ij p_j); match
arrays are (M, 2) int64 index pairs (index into frame i's keypoints, index into frame j's).

- :mod:`.keypoints`: OpenCV SIFT with a cap on the number per frame;
- :mod:`.points`: depth sampling at keypoints and lifting to 3D;
- :mod:`.ground_truth`: ground-truth matches from depth + poses (the one implementation);
- :mod:`.descriptors`: mutual-nearest-neighbour matching (cosine or L2, optional ratio test)
  and bilinear sampling of a dense descriptor map at keypoints;
- :mod:`.kabsch`: weighted Kabsch rigid fit;
- :mod:`.filters`: keypoint correspondence filter + surface area filter (BundleFusion);
- :mod:`.match_accuracy`: precision / recall of found matches against the ground truth;
- :mod:`.visual`: match images (correct green, wrong red).
"""

from c3f_slam.matching.descriptors import mutual_nearest_neighbours, sample_descriptor_map
from c3f_slam.matching.filters import FilterResult, MatchFilterConfig, filter_matches
from c3f_slam.matching.ground_truth import Projection, ground_truth_matches, project_keypoints
from c3f_slam.matching.kabsch import kabsch
from c3f_slam.matching.keypoints import Keypoints, detect_sift, to_gray_uint8
from c3f_slam.matching.match_accuracy import MatchCounts, classify_matches, evaluate_matches, near_misses
from c3f_slam.matching.points import lift_keypoints, sample_depth

__all__ = [
    "FilterResult",
    "Keypoints",
    "MatchCounts",
    "MatchFilterConfig",
    "Projection",
    "classify_matches",
    "detect_sift",
    "evaluate_matches",
    "filter_matches",
    "ground_truth_matches",
    "kabsch",
    "lift_keypoints",
    "mutual_nearest_neighbours",
    "near_misses",
    "project_keypoints",
    "sample_depth",
    "sample_descriptor_map",
    "to_gray_uint8",
]
