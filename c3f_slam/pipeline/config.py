"""Settings of the SLAM runtime (SPEC §4), with presets per data kind.

All lengths are metres. ``colon`` (default) and ``room`` pick the match filter, pose-graph
and TSDF presets of :mod:`c3f_slam.matching`, :mod:`c3f_slam.posegraph` and
:mod:`c3f_slam.fusion`; the fragment rules are the paper's (100 correspondences, 85 %
frustum overlap) unless overridden.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields, replace

from c3f_slam.errors import InputError
from c3f_slam.fusion import TSDF_PRESETS, TSDFConfig
from c3f_slam.matching import MatchFilterConfig
from c3f_slam.pipeline.retrieval import CandidateConfig
from c3f_slam.posegraph import POSEGRAPH_PRESETS, PoseGraphConfig

PRESETS = ("colon", "room")
MODES = ("full", "odometry")
#: SlamConfig overrides that restore the paper's literal rules at any map size: every new
#: keyframe matched against all keyframes, all its accepted matches kept, the whole
#: component optimised after every loop or merge (quadratic on long sequences), every
#: fragment's first frame a keyframe (memory grows with every revisit)
PAPER_RULES = dict(max_keyframe_candidates=None, max_loop_edges_per_keyframe=None, optimize_growth=None,
                   max_optimize_nodes=None, final_optimize_nodes=None, reuse_keyframes=False)


@dataclass(frozen=True)
class SlamConfig:
    """Runtime options.

    Frontend: ``max_keypoints`` SIFT keypoints per frame (strongest first) outside specular
    highlights (``mask_specular``); ``sift_contrast_threshold`` (OpenCV's 0.04 finds too few
    keypoints on small, smooth colon frames); ``specular_dilation_px`` dilation of the
    specular mask (None: SPEC 2's 13 px scaled by min(W, H) / 512, at least 3 px, since a
    13 px dilation masks a third of a 128 px frame); ``ratio`` Lowe ratio test on top of the mutual
    nearest neighbours (None = off); ``keyframe_keypoints`` cap of what a keyframe keeps for
    global matching (compact: uint8 SIFT, float32 points).

    Fragments (SPEC §4.2): a frame opens a new fragment when fewer than
    ``min_consecutive_correspondences`` filtered correspondences link it to the previous
    frame, or when its frustum overlap with the active keyframe is below ``min_overlap``
    (evaluated on a grid of ``overlap_stride`` px); ``max_fragment_frames`` bounds a fragment
    (memory). ``intra_all_pairs``: also match each new frame against every frame of the
    active fragment (not only the previous one and the keyframe).

    Global (SPEC §4.2, bounded so that time per frame does not grow with the map):

    - Candidates (:mod:`c3f_slam.pipeline.retrieval`): the paper matches each new keyframe
      against *all* earlier keyframes. Here, once the map has more than
      ``max_keyframe_candidates`` keyframes, a new keyframe is matched against at most that
      many: the ``recent_keyframe_candidates`` most recent ones, up to
      ``spatial_keyframe_candidates`` keyframes near its odometry pose estimate (camera centre
      within ``spatial_radius`` metres, viewing direction within ``spatial_max_angle_deg``)
      and the rest by global appearance over all keyframes. Maps up to the cap match all
      keyframes exactly as the paper; ``max_keyframe_candidates=None`` always does (quadratic).
    - Loop edges: ``max_loop_edges_per_keyframe`` (a count of edges, default 8) bounds the
      keyframe-match edges (kinds ``keyframe`` and ``loop``, the uncertain ones) a new
      keyframe adds to the global graph, which otherwise grow with how often a place is
      revisited (~20 per keyframe on a ping-pong stream, the graph's memory): of its accepted
      matches it keeps the one to the most recent keyframe, the strongest match into each
      other component it reaches (so no merge is lost), then the strongest others (most inlier
      correspondences), and discards the rest (deviation from the paper on revisit-heavy
      streams). The odometry edge is always kept and not counted. ``None`` or 0 keeps all
      accepted matches (the paper).
    - Optimisation: ``optimize_every_keyframe`` runs the global pose graph after a keyframe
      that adds a loop edge or merges components (odometry-only keyframes are chained) and
      always at the end (False: only at the end). Rate limit (deviation from the paper on
      big maps): while the map has fewer than ``optimize_small_map`` keyframes every such
      keyframe optimises; beyond, an optimisation waits until the keyframes added since the
      last one are at least ``optimize_growth`` x the nodes it would optimise (the new
      keyframe's component, at most ``max_optimize_nodes``): a geometric schedule (about
      5 % growth) while whole components are optimised, a fixed gap for windows; a skipped
      trigger is remembered and runs at the next due keyframe. ``optimize_growth=None``
      optimises after every such keyframe. ``max_optimize_nodes``: a component larger than
      this is optimised in a bounded window (breadth first over the graph from the new
      keyframe(s)) with the rest held fixed, because Open3D's solver is dense (cubic in the
      nodes); None = always the whole component (the paper). ``window_boundary_edges``: per
      window node, at most this many edges to fixed newer keyframes (old keyframes of a
      revisited place collect many); None = all. At the end (``finish``) the main component
      is optimised whole when it has at most ``final_optimize_nodes`` keyframes (None:
      always), else by one sweep of overlapping ``max_optimize_nodes`` windows in keyframe
      order.
    - Revisits: ``reuse_keyframes`` (deviation from the paper, which makes every fragment's
      first frame a keyframe): a new fragment whose first frame could continue the fragment
      of an earlier keyframe by the fragment rules (at least
      ``min_consecutive_correspondences`` correspondences with it and frustum overlap
      >= ``min_overlap``) hangs off that keyframe instead: no new node, no stored features,
      and only the edges that add information (a merge of components, the loop closure
      of a fragment that made a new keyframe). When the frame also has an odometry link
      into that keyframe's component, the two must agree on its pose (camera centres within
      ``reuse_max_offset`` metres, orientations within ``reuse_max_angle_deg``); otherwise it
      becomes a keyframe with uncertain edges as in the paper, so that a wrong keyframe
      match can still be pruned by the pose-graph optimisation. A stream that keeps
      revisiting mapped places then stops adding keyframes and edges, so memory stays
      flat; new places still add them. ``PAPER_RULES`` turns it off.
    - Keyframe storage: ``keyframe_cache`` (default True): :func:`c3f_slam.pipeline.run.run_slam`
      keeps the stored keyframes' descriptors and 3D points in a file under
      ``OUT/.keyframe_cache`` (removed at the end of the run, also on errors) and only a
      34-byte record per keyframe plus an LRU of 64 keyframes in RAM; False keeps them in RAM
      (~5 KB per keyframe with SIFT). Results are identical either way.

    Threads: ``blas_threads`` caps the BLAS (OpenBLAS / MKL) threads NumPy uses during a run
    (threadpoolctl; None leaves the library's setting). The runtime's matrices are small (a
    ~100x128 descriptor product per frame pair, 3x3 SVDs): a second OpenBLAS thread gains
    nothing on an idle machine and made whole runs 1.7-2.8x slower when other jobs shared the
    cores (benchmarks/results/slam_blas_threads.md); 1 is the default.

    Fusion: ``fuse`` (False = --no-mesh), ``eps_f_na`` frames and ``eps_cf_d`` metres (the
    settle rule of :class:`c3f_slam.fusion.FragmentFusion`), ``tsdf`` volume settings.
    """

    preset: str = "colon"
    mode: str = "full"
    max_keypoints: int = 1000
    sift_contrast_threshold: float = 0.005
    mask_specular: bool = True
    specular_dilation_px: int | None = None
    ratio: float | None = 0.9
    keyframe_keypoints: int = 1000
    min_consecutive_correspondences: int = 100
    min_overlap: float = 0.85
    overlap_stride: int = 4
    max_fragment_frames: int = 60
    intra_all_pairs: bool = True
    optimize_every_keyframe: bool = True
    max_keyframe_candidates: int | None = 24
    max_loop_edges_per_keyframe: int | None = 8
    recent_keyframe_candidates: int = 4
    spatial_keyframe_candidates: int = 8
    spatial_radius: float = 0.02
    spatial_max_angle_deg: float = 60.0
    optimize_growth: float | None = 0.05
    optimize_small_map: int = 40
    max_optimize_nodes: int | None = 100
    window_boundary_edges: int | None = 8
    final_optimize_nodes: int | None = 600
    reuse_keyframes: bool = True
    reuse_max_offset: float = 0.005
    reuse_max_angle_deg: float = 10.0
    keyframe_cache: bool = True
    blas_threads: int | None = 1
    match_filter: MatchFilterConfig = field(default_factory=MatchFilterConfig.colon)
    posegraph: PoseGraphConfig = field(default_factory=lambda: POSEGRAPH_PRESETS["colon"])
    tsdf: TSDFConfig = field(default_factory=lambda: TSDF_PRESETS["colon"])
    fuse: bool = True
    eps_f_na: int = 30
    eps_cf_d: float = 0.05

    def __post_init__(self) -> None:
        if self.preset not in PRESETS:
            raise InputError(f"--preset must be one of {PRESETS}, got {self.preset!r}")
        if self.mode not in MODES:
            raise InputError(f"--baseline/mode must be one of {MODES}, got {self.mode!r}")
        if self.max_keypoints < 10 or self.keyframe_keypoints < 10:
            raise InputError("max_keypoints and keyframe_keypoints must be >= 10")
        if not 0.0 <= self.min_overlap <= 1.0:
            raise InputError(f"min_overlap must be in [0, 1], got {self.min_overlap}")
        if self.min_consecutive_correspondences < 0:
            raise InputError("min_consecutive_correspondences must be >= 0")
        if self.max_fragment_frames < 1:
            raise InputError("max_fragment_frames must be >= 1")
        if self.max_keyframe_candidates is not None and self.max_keyframe_candidates < 1:
            raise InputError("max_keyframe_candidates must be >= 1 (or None: all keyframes)")
        if self.max_loop_edges_per_keyframe is not None and self.max_loop_edges_per_keyframe < 0:
            raise InputError("max_loop_edges_per_keyframe must be >= 0 (0 or None: keep all), "
                             f"got {self.max_loop_edges_per_keyframe}")
        if self.recent_keyframe_candidates < 0 or self.spatial_keyframe_candidates < 0:
            raise InputError("recent_keyframe_candidates and spatial_keyframe_candidates must be >= 0")
        if self.optimize_growth is not None and self.optimize_growth < 0:
            raise InputError("optimize_growth must be >= 0 (or None: after every keyframe)")
        if self.window_boundary_edges is not None and self.window_boundary_edges < 0:
            raise InputError("window_boundary_edges must be >= 0 (or None: all)")
        if self.reuse_max_offset < 0 or not 0 <= self.reuse_max_angle_deg <= 180:
            raise InputError("reuse_max_offset must be >= 0 (metres) and reuse_max_angle_deg in [0, 180], got "
                             f"{self.reuse_max_offset}, {self.reuse_max_angle_deg}")
        if self.blas_threads is not None and self.blas_threads < 1:
            raise InputError(f"blas_threads must be >= 1 (or None: the BLAS library's default), got {self.blas_threads}")
        for name in ("max_optimize_nodes", "final_optimize_nodes"):
            v = getattr(self, name)
            if v is not None and v < 2:
                raise InputError(f"{name} must be >= 2 (or None: whole components)")

    @property
    def candidates(self) -> CandidateConfig:
        """The keyframe candidate settings (:mod:`c3f_slam.pipeline.retrieval`)."""
        return CandidateConfig(
            max_candidates=self.max_keyframe_candidates,
            recent=self.recent_keyframe_candidates,
            spatial=self.spatial_keyframe_candidates,
            spatial_radius=self.spatial_radius,
            spatial_max_angle_deg=self.spatial_max_angle_deg,
        )

    @classmethod
    def preset_config(cls, name: str = "colon", **overrides) -> "SlamConfig":
        """Defaults for ``colon`` (mm scale) or ``room`` (cm scale; fusion settles after 1 m,
        spatial keyframe candidates within 1 m instead of 2 cm, keyframe reuse
        within 25 cm of the odometry instead of 5 mm)."""
        if name not in PRESETS:
            raise InputError(f"--preset must be one of {PRESETS}, got {name!r}")
        base = dict(
            preset=name,
            match_filter=MatchFilterConfig.preset(name),
            posegraph=POSEGRAPH_PRESETS[name],
            tsdf=TSDF_PRESETS[name],
            eps_cf_d=0.05 if name == "colon" else 1.0,
            spatial_radius=0.02 if name == "colon" else 1.0,
            reuse_max_offset=0.005 if name == "colon" else 0.25,
        )
        known = {f.name for f in fields(cls)}
        bad = sorted(set(overrides) - known)
        if bad:
            raise InputError(f"unknown SLAM option(s): {', '.join(bad)}")
        return cls(**{**base, **overrides})

    def with_(self, **changes) -> "SlamConfig":
        return replace(self, **changes)

    def as_dict(self) -> dict:
        out = {}
        for f in fields(self):
            v = getattr(self, f.name)
            out[f.name] = v.__dict__ if hasattr(v, "__dict__") else v
        return out
