"""Settings of the camera path's smoothness on predicted depth
(docs/design.md, Smooth trajectories on predicted depth): the constant-velocity motion prior on the final path
(:mod:`c3f_slam.pipeline.smoothing`), resolved from the depth source when a run starts
(:meth:`SmoothingConfig.for_depth_source`). Times in seconds."""

from __future__ import annotations

from dataclasses import dataclass, replace

from c3f_slam.config.checks import at_least, check

#: the motion prior's time constant on predicted depth (``smoothing.motion_prior_s`` None with
#: ``--depth-source model``); depth files (sensor or ground truth) take 0 (off)
PREDICTED_DEPTH_MOTION_PRIOR_S = 0.1


@dataclass(frozen=True)
class SmoothingConfig:
    """A smooth camera path on predicted depth.

    After the final optimisation, the registered frames' poses (positions and orientations) are
    refitted under a constant-velocity prior: they minimise the squared distance to the graph's
    poses plus tau^4 x the squared acceleration, both integrated over time (a
    Whittaker-Henderson smoother, :func:`c3f_slam.pipeline.smoothing.smooth_poses`). A path at
    constant velocity passes whatever its speed; changes of velocity faster than about 1 / tau
    rad/s are damped (half power at 1 / (2 pi tau) Hz: 1.6 Hz at 0.1 s), unless they stand out
    from the path's usual ones by more than ``robust_k`` (Huber weights), so that a true turn or
    burst keeps its sharpness (the simulator's random paths: ATE 0.385 -> 0.474 cm without them,
    0.357 with them). trajectory.txt, fusion,
    the unseen-wall estimate and the checks all use the smoothed poses. On the zoo's predicted
    depth each frame's registration is off by about the camera's motion per frame (0.3-0.8 mm
    and 0.5-1 deg at the paper's pace), so the graph's path zigzags about the true one (1.4-1.6
    times the truth's jitter ratio on the simulator); with the prior it is within 1 % of the
    truth's. On depth files it does not zigzag, and the prior would only take true motion out
    (ground-truth depth: ATE 0.022 -> 0.038 cm at 0.1 s), so there it is off.
    """

    #: seconds: time constant tau of the constant-velocity prior on the final path (0 = off).
    #: None: from the depth source (:data:`PREDICTED_DEPTH_MOTION_PRIOR_S` on predicted depth, 0 on files)
    motion_prior_s: float | None = None
    #: seconds: the prior does not reach across a longer gap between two registered frames (the
    #: path is smoothed piecewise)
    max_gap_s: float = 0.5
    #: a frame whose smoothed acceleration (in position or orientation) exceeds this many times the
    #: path's median one weighs the prior down in proportion (Huber); 0: the plain quadratic prior
    robust_k: float = 3.0
    robust_iterations: int = 3  #: reweighting passes of the robust prior (each one banded solve)

    def __post_init__(self) -> None:
        at_least(self.motion_prior_s, 0.0, "smoothing.motion_prior_s", "from the depth source")
        check(self.max_gap_s > 0, f"smoothing.max_gap_s must be > 0 (seconds), got {self.max_gap_s}")
        check(self.robust_k == 0 or self.robust_k >= 1,
              f"smoothing.robust_k must be 0 (off) or >= 1, got {self.robust_k}")
        at_least(self.robust_iterations, 1, "smoothing.robust_iterations")

    @property
    def prior_s(self) -> float:
        """The motion prior's time constant in use: ``motion_prior_s``, 0 while unresolved."""
        return self.motion_prior_s or 0.0

    def for_depth_source(self, depth_source: str) -> SmoothingConfig:
        """These settings with ``motion_prior_s``, when unset, resolved for ``depth_source``
        (``model``: :data:`PREDICTED_DEPTH_MOTION_PRIOR_S`; ``files``: 0); a given value stays."""
        if self.motion_prior_s is not None:
            return self
        return replace(self, motion_prior_s=PREDICTED_DEPTH_MOTION_PRIOR_S if depth_source == "model" else 0.0)
