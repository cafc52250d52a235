"""Settings of the global map: keyframe candidates, what a keyframe keeps and revisits, dense
edge refinement, the pose graph and its optimisation schedule, and the components written
beside the main map. Lengths in metres, angles in degrees; each group checks its own fields.
The values of the ``room`` preset: :mod:`c3f_slam.config.presets`."""

from __future__ import annotations

from dataclasses import dataclass

from c3f_slam.config.checks import at_least, check


@dataclass(frozen=True)
class CandidateConfig:
    """Which earlier keyframes a new keyframe is matched against (:mod:`c3f_slam.pipeline.retrieval`);
    metres, degrees."""

    max_candidates: int | None = 24  #: at most this many once the map is bigger; None = all (quadratic)
    recent: int = 4  #: the most recent keyframes
    spatial: int = 8  #: keyframes near the odometry pose estimate ...
    spatial_radius: float = 0.02  #: ... camera centre within this distance ...
    spatial_max_angle_deg: float = 60.0  #: ... and viewing direction within this angle

    def __post_init__(self) -> None:
        at_least(self.max_candidates, 1, "candidates.max_candidates", "all keyframes")
        at_least(self.recent, 0, "candidates.recent")
        at_least(self.spatial, 0, "candidates.spatial")


@dataclass(frozen=True)
class KeyframeConfig:
    """What a keyframe keeps and adds to the global graph, and revisits (:mod:`c3f_slam.pipeline.reuse`)."""

    keypoints: int = 1000  #: features a keyframe keeps for global matching (compact copies)
    #: keyframe-match (loop) edges a new keyframe adds (:func:`cap_keyframe_edges`); None = all (the paper)
    max_loop_edges: int | None = 8
    reuse: bool = True  #: a fragment that revisits a mapped place hangs off that place's keyframe
    reuse_max_offset: float = 0.005  #: metres: a reuse must agree with the odometry link this well ...
    reuse_max_angle_deg: float = 10.0  #: ... and within this angle
    #: where a reusing fragment's first frame goes relative to its host keyframe: 0 = where the
    #: host's match puts it, 1 = where the odometry link from the frame before puts it (when there
    #: is one into the host's component), in between: that share of the way from the first to the
    #: second. The two disagree by up to ``reuse_max_offset``; on predicted depth by about 0.5 mm,
    #: which the host's match alone (0) turned into steps of the path: on the phantom clip 0.5 took
    #: its jitter ratio from 2.61 to 2.24 (docs/design.md, Smooth trajectories on predicted depth)
    reuse_odometry_weight: float = 0.5
    cache: bool = True  #: stored features on disk under OUT/.keyframe_cache (same results, flat RAM)

    def __post_init__(self) -> None:
        at_least(self.keypoints, 10, "keyframes.keypoints")
        at_least(self.max_loop_edges, 0, "keyframes.max_loop_edges", "keep all")
        check(0.0 <= self.reuse_odometry_weight <= 1.0,
              f"keyframes.reuse_odometry_weight must be in [0, 1], got {self.reuse_odometry_weight}")
        check(self.reuse_max_offset >= 0 and 0 <= self.reuse_max_angle_deg <= 180,
               "keyframes.reuse_max_offset must be >= 0 (metres) and keyframes.reuse_max_angle_deg in [0, 180], "
               f"got {self.reuse_max_offset}, {self.reuse_max_angle_deg}")


@dataclass(frozen=True)
class RefineConfig:
    """Dense refinement of keyframe-to-keyframe edges with Open3D's coloured ICP
    (:mod:`c3f_slam.pipeline.refine`). Lengths in metres: ``voxels`` coarse to fine (the
    preset's scale: room cm, colon mm), one ICP per voxel size with ``iterations`` each. Off by
    default for both presets: it did not lower the ATE on a synthetic room sequence nor on a
    simulator colon one (docs/lab_notes/2026-12-02-slam-dense-refine.md)."""

    enabled: bool = False  #: refine each new keyframe's edges
    voxels: tuple[float, ...] = (0.002, 0.001, 0.0005)  #: voxel sizes, coarse to fine (metres)
    iterations: tuple[int, ...] = (30, 20, 10)  #: ICP iterations per voxel size
    max_correction: float = 0.005  #: metres: a refined pose further from the sparse one is rejected ...
    max_correction_deg: float = 5.0  #: ... as is a larger rotation between them (degrees)
    min_fitness: float = 0.5  #: share of the new keyframe's points within 1.5 voxels after refining
    min_gain: float = 0.02  #: the fitness must rise at least this much over the sparse pose's (0: any)
    max_edges: int = 4  #: edges refined per new keyframe (odometry first, then the strongest)
    cache: int = 64  #: keyframes whose clouds are kept (the most recent; older edges stay sparse)
    stride: int = 2  #: pixel grid of the keyframes' clouds

    def __post_init__(self) -> None:
        check(len(self.voxels) >= 1 and len(self.voxels) == len(self.iterations)
               and all(v > 0 for v in self.voxels) and all(i >= 1 for i in self.iterations),
               f"refine.voxels and refine.iterations must be equally long, > 0, got {self.voxels}, {self.iterations}")
        check(self.max_correction > 0 and 0 < self.max_correction_deg <= 180,
               "refine.max_correction must be > 0 (metres) and refine.max_correction_deg in (0, 180], "
               f"got {self.max_correction}, {self.max_correction_deg}")
        check(0 <= self.min_fitness <= 1 and 0 <= self.min_gain <= 1,
               f"refine.min_fitness and refine.min_gain must be in [0, 1], got {self.min_fitness}, {self.min_gain}")
        for name in ("max_edges", "cache", "stride"):
            at_least(getattr(self, name), 1, f"refine.{name}")



@dataclass(frozen=True)
class PoseGraphConfig:
    """Pose-graph optimisation (Open3D's, with line-process pruning of uncertain edges); metres.

    - ``max_correspondence_distance``: the misalignment (RMS over an edge's points) at which
      an uncertain edge starts being distrusted; also the internal length unit.
    - ``edge_prune_threshold``: line-process confidence below which an uncertain edge is pruned.
    - ``preference_loop_closure``: weight of loop closures against odometry (larger keeps
      more loop edges).
    """

    max_correspondence_distance: float = 0.003  #: metres: an uncertain edge is distrusted from this misalignment
    edge_prune_threshold: float = 0.25  #: line-process confidence below which an uncertain edge is pruned
    preference_loop_closure: float = 1.0  #: weight of loop closures against odometry
    max_iterations: int = 100  #: Levenberg-Marquardt iterations

    def __post_init__(self) -> None:
        check(self.max_correspondence_distance > 0,
              f"posegraph.max_correspondence_distance must be > 0 (metres), got {self.max_correspondence_distance}")
        check(0 <= self.edge_prune_threshold <= 1,
              f"posegraph.edge_prune_threshold must be in [0, 1], got {self.edge_prune_threshold}")
        check(self.preference_loop_closure > 0,
              f"posegraph.preference_loop_closure must be > 0, got {self.preference_loop_closure}")
        at_least(self.max_iterations, 1, "posegraph.max_iterations")


@dataclass(frozen=True)
class OptimizationConfig:
    """When and how much of the global graph is optimised (:mod:`c3f_slam.pipeline.schedule`)."""

    every_keyframe: bool = True  #: after a keyframe that adds a loop or merges (False: only at the end)
    growth: float | None = 0.05  #: rate limit on big maps; None = after every such keyframe (the paper)
    small_map: int = 40  #: below this many keyframes every trigger optimises
    max_nodes: int | None = 100  #: bigger components are optimised in windows of this many; None = whole
    window_boundary_edges: int | None = 8  #: per window node, edges to fixed newer keyframes; None = all
    final_nodes: int | None = 600  #: at the end, whole up to this size, else one sweep of windows

    def __post_init__(self) -> None:
        at_least(self.growth, 0, "optimization.growth", "after every keyframe")
        at_least(self.window_boundary_edges, 0, "optimization.window_boundary_edges", "all")
        for name in ("max_nodes", "final_nodes"):
            at_least(getattr(self, name), 2, f"optimization.{name}", "whole components")


@dataclass(frozen=True)
class ComponentConfig:
    """What becomes of the components that could not be joined to the main map
    (:mod:`c3f_slam.pipeline.components`; frames = registered frames of a component)."""

    #: a component other than the main map with at least this many frames is optimised, fused
    #: and written to OUT/components/NN/; 0 = none is
    min_frames: int = 30
    max_written: int = 8  #: at most this many of them, the largest ones

    def __post_init__(self) -> None:
        at_least(self.min_frames, 0, "components.min_frames")
        at_least(self.max_written, 0, "components.max_written")

    def writes(self, frames: int, rank: int) -> str | None:
        """Why a component with ``frames`` frames, the ``rank``-th largest besides the main map
        (from 1), is not written (None: it is)."""
        if self.min_frames <= 0:
            return "off"
        if frames < self.min_frames:
            return "below_min_frames"
        if rank > self.max_written:
            return "over_max_written"
        return None
