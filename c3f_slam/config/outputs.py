"""Settings of the outputs: TSDF fusion (its volume) and the
unseen-wall estimate. Lengths in metres; each group checks its own fields. The values of the
``room`` preset: :mod:`c3f_slam.config.presets`."""

from __future__ import annotations

from dataclasses import dataclass, field

from c3f_core.errors import InputError
from c3f_slam.config.checks import at_least, check


@dataclass(frozen=True)
class TSDFConfig:
    """TSDF options (metres). ``weight_threshold``: minimum fused weight for a surface."""

    voxel_size: float = 0.001  #: metres: voxel edge
    trunc: float = 0.004  #: metres: truncation distance of the signed distance
    depth_min: float = 0.001  #: metres: nearer depth is not integrated ...
    depth_max: float = 0.2  #: ... nor farther depth
    block_resolution: int = 8  #: voxels per block edge (Open3D's VoxelBlockGrid)
    block_count: int = 20_000  #: blocks reserved at first (the hash map grows on demand)
    weight_threshold: float = 1.0  #: minimum fused weight for a surface

    def __post_init__(self) -> None:
        check(self.voxel_size > 0 and self.trunc > 0,
              f"fusion.tsdf.voxel_size and fusion.tsdf.trunc must be > 0 (metres), got {self.voxel_size}, {self.trunc}")
        check(0 <= self.depth_min < self.depth_max,
              f"fusion.tsdf needs 0 <= depth_min < depth_max (metres), got {self.depth_min}, {self.depth_max}")
        at_least(self.block_resolution, 1, "fusion.tsdf.block_resolution")
        at_least(self.block_count, 1, "fusion.tsdf.block_count")


@dataclass(frozen=True)
class FusionConfig:
    """TSDF fusion of the map with its final poses (:class:`c3f_slam.fusion.tsdf.FragmentFusion`)."""

    enabled: bool = True  #: fuse a mesh (and so estimate the unseen wall)
    tsdf: TSDFConfig = field(default_factory=TSDFConfig)  #: the volume


@dataclass(frozen=True)
class CoverageConfig:
    """How the wall is modelled and when a wall cell counts as observed.

    The wall is cut into cells of ``cell_length`` metres of centreline by ``angle_bins``
    angles around it. A cell is observed when at least one registered frame has it inside
    its image, at a depth (z) in [``depth_min``, ``depth_max``] (None: the range TSDF fusion
    integrates), and not hidden by the reconstructed surface (a ray cast that stops more than
    ``occlusion_tol`` + ``occlusion_tol_rel`` x distance before it). With ``require_surface``
    a cell also needs surface of the mesh in it: what fusion saw it reconstructed, so a hole
    in the reconstruction is unseen wall whatever the filled-in wall model predicts (the
    true mesh of the ground truth has surface everywhere).
    """

    enabled: bool = True  #: estimate the unseen wall (coverage.json, coverage_map.png, unseen.ply)
    segment: float = 0.05  #: segment length along the centreline for the per-segment shares
    cell_length: float = 0.002  #: wall cell length along the centreline
    angle_bins: int = 90  #: wall cells around the centreline
    node_spacing: float = 0.005  #: the centreline grows by a node per this much forward camera travel
    smoothing: float = 0.01  #: Gaussian sigma (metres of centreline) smoothing the camera path
    max_radius: float = 0.06  #: surface farther from the centreline is not wall of this segment
    fill_gap: float = 0.02  #: unobserved wall up to this long is interpolated along the centreline first
    depth_min: float | None = None  #: None: the fusion's depth range
    depth_max: float | None = None  #: None: the fusion's depth range
    occlusion_tol: float = 0.001  #: metres a ray may stop before a cell and still see it ...
    occlusion_tol_rel: float = 0.02  #: ... plus this share of the distance
    require_surface: bool = True  #: a cell also needs reconstructed surface in it to count as seen
    max_frames: int = 600  #: frames tested for visibility (evenly spaced subset of the registered ones)
    #: the live estimate (``live``) counts a cell as observed once this many depth points landed in it
    #: (one stray point of noisy predicted depth is not a view of the wall)
    live_min_points: int = 4

    def __post_init__(self) -> None:
        for name in ("segment", "cell_length", "node_spacing", "max_radius"):
            if not getattr(self, name) > 0:
                raise InputError(f"coverage.{name} must be > 0 (metres), got {getattr(self, name)}")
        if self.live_min_points < 1:
            raise InputError(f"coverage.live_min_points must be >= 1, got {self.live_min_points}")
        if self.angle_bins < 8 or self.max_frames < 1:
            raise InputError(f"coverage.angle_bins must be >= 8 and coverage.max_frames >= 1, got "
                             f"{self.angle_bins}, {self.max_frames}")
        if self.smoothing < 0 or self.fill_gap < 0 or self.occlusion_tol < 0 or self.occlusion_tol_rel < 0:
            raise InputError("coverage.smoothing, fill_gap, occlusion_tol and occlusion_tol_rel must be >= 0")

    def depth_range(self, fusion_min: float, fusion_max: float) -> tuple[float, float]:
        """(near, far) metres: the configured range, else fusion's."""
        near = fusion_min if self.depth_min is None else self.depth_min
        far = fusion_max if self.depth_max is None else self.depth_max
        if not 0 <= near < far:
            raise InputError(f"coverage depth range must satisfy 0 <= near < far, got {near}, {far}")
        return near, far


@dataclass(frozen=True)
class ChecksConfig:
    """Checks of a finished run that need no ground truth (:mod:`c3f_slam.pipeline.self_checks`):
    photometric and depth agreement of re-read frames with the map, depth agreement of
    neighbouring keyframes, and the trajectory's jitter ratio."""

    enabled: bool = True  #: re-read frames and compare them with the map (the jitter ratio is always given)
    frames: int = 40  #: frames compared with the map, evenly spread over the registered ones (and keyframe pairs)
    size_px: int = 160  #: renders and comparisons at most this many pixels on the long side
    jitter_window_s: float = 1.0  #: the moving average the jitter ratio compares the path with, seconds

    def __post_init__(self) -> None:
        at_least(self.frames, 2, "checks.frames")
        at_least(self.size_px, 16, "checks.size_px")
        check(self.jitter_window_s > 0, f"checks.jitter_window_s must be > 0 (seconds), got {self.jitter_window_s}")
