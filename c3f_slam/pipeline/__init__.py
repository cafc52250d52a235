"""The SLAM runtime pipeline (SPEC §4): frontend, fragments, global keyframe graph, fusion.

- :mod:`.config`: :class:`SlamConfig` and presets (colon / room);
- :mod:`.frontend`: keypoints, descriptor / depth provider seams, pairwise matching;
- :mod:`.fusion_frames`: where fusion re-reads frames (sequence files, or the predicted-depth cache);
- :mod:`.fragments`: the new-fragment rule and the intra-fragment pose graph;
- :mod:`.retrieval`: the bounded set of keyframes a new keyframe is matched against;
- :mod:`.slam`: the fragment + global keyframe back-end and the odometry baseline;
- :mod:`.run`: the streaming run loop that writes the outputs;
- :mod:`.run_evaluation`: the ``evaluate`` command: a run folder against ground truth (metrics and files).
"""

from c3f_slam.pipeline.config import PAPER_RULES, SlamConfig
from c3f_slam.pipeline.run import run_slam

__all__ = ["PAPER_RULES", "SlamConfig", "run_slam"]
