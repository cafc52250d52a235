"""The SLAM runtime pipeline (docs/design.md, SLAM runtime): frontend, fragments, global keyframe graph, fusion.

- :mod:`.sources`: the run's inputs (:class:`RunInputs`), checked and opened once;
- :mod:`.frontend`: keypoints, descriptor / depth provider seams, pairwise matching;
- :mod:`.backend`: the :class:`SlamBackend` and ``SlamMap`` protocols the run loop drives and
  reads, and the frame log;
- :mod:`.frame_step`: a frame's inputs to a back-end (``FrameInput``) and its decision (``FrameDecision``);
- :mod:`.timings`: seconds per stage;
- :mod:`.slam`: the full back-end (fragments + global keyframe graph): the tracker, holding its
  map (:mod:`.fragment_map`) and the placement of new fragments (:mod:`.placement`), built from
  :mod:`.fragments` (the new-fragment rule, intra-fragment graphs), :mod:`.retrieval`
  (keyframe candidates), :mod:`.keyframe_edges` (edge cap, placing a keyframe),
  :mod:`.reuse` (revisits), :mod:`.rejoin` (tracking breaks), :mod:`.schedule` (global
  optimisation), :mod:`.keyframe_store`;
- :mod:`.components`: the components of the map beside the main one (``OUT/components/``);
- :mod:`.odometry`: the frame-to-frame baseline back-end;
- :mod:`.fusion_frames`: where fusion re-reads frames (sequence files, or the predicted-depth cache);
- :mod:`.run`: :func:`run_slam` and the :class:`SlamRun` that owns a run's resources;
- :mod:`.run_evaluation`: the ``evaluate`` command: a run folder against ground truth (metrics and files).
"""

from c3f_slam.config import PAPER_RULES, SlamConfig  # the settings tree (c3f_slam.config), for convenience
from c3f_slam.pipeline.run import run_slam
from c3f_slam.pipeline.sources import RunInputs

__all__ = ["PAPER_RULES", "RunInputs", "SlamConfig", "run_slam"]
