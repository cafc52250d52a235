"""Settings of the demo (``python -m c3f_demo``): one small frozen dataclass per stage.

Lengths are metres, frame sizes pixels (square). :func:`demo_config` gives the presets: the
default and ``quick`` (a few minutes, for CI), each starting from the zoo's models (only the
test-time training on the held-out sequence trains) or, ``from_scratch``, training both
networks first. :func:`video_config` gives the run on a user's own video (``--video``): no
simulator, the video's frames instead of the held-out sequence, no ground truth.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, replace

ZOO_SIZE = 128  #: frame size of the zoo models (pixels)
ZOO_TTT_STEPS = 60  #: test-time training steps from the zoo weights (the paper's objective)


@dataclass(frozen=True)
class SimulateConfig:
    """Simulator sequences (``python -m datamodules.synthetic generate``).

    ``train``: (preset, seed) of each training sequence; ``test``: the held-out one. ``coverage``:
    share of the colon each path travels (``path.coverage``); at ``frames`` frames this sets the
    motion per frame (docs/datasets.md, Speed per frame).
    """

    train: tuple[tuple[str, int], ...] = (("seq1", 100), ("seq3", 101))
    test: tuple[str, int] = ("seq1", 200)
    train_frames: int = 200
    test_frames: int = 150
    size: int = 128
    train_coverage: float = 0.10
    test_coverage: float = 0.075


@dataclass(frozen=True)
class DepthTrainConfig:
    """DepthNet training (``configs/depthnet/small.yaml`` + the Monodepth2 override).

    ``lambda_gt_depth``: weight of the supervised term on the simulator's true depth
    (``model.loss.lambda_gt_depth``; 0 = the paper's self-supervised objective only).
    ``paper_extras``: keep C3Fusion's extra terms (L_ph-extra, L_dc, outlier and specular
    masks); off by default here, they triple the cost per step. ``lr``: AdamW learning rate
    (None: the model config's, 1e-4).
    """

    steps: int = 300
    size: int = 64
    batch_size: int = 4
    lambda_gt_depth: float = 1.0
    paper_extras: bool = False
    seed: int = 7
    lr: float | None = None


@dataclass(frozen=True)
class TestTimeConfig:
    """Self-supervised test-time training of DepthNet on the held-out sequence, after the
    pre-training (``configs/depthnet/ttt.yaml``; no ground truth). ``steps`` 0: off, SLAM uses
    the pre-trained network. Same frame size and loss terms as the pre-training. The first
    ``pose_warmup_steps`` train PoseNet alone (``model.pose_warmup_steps``)."""

    steps: int = 60
    batch_size: int = 4
    lr: float = 1e-4
    seed: int = 7
    pose_warmup_steps: int = 30


@dataclass(frozen=True)
class FeatureTrainConfig:
    """ContraFeat training (``configs/contrafeat/small.yaml``)."""

    steps: int = 80
    size: int = 128
    batch_size: int = 2
    seed: int = 7


@dataclass(frozen=True)
class ReportConfig:
    """What the report shows: ``sample_frames`` frames of the held-out sequence with depth,
    the match pair ``pair`` = (i, i + gap), mesh renders of ``render_size`` pixels."""

    sample_frames: int = 4
    depth_eval_stride: int = 2
    pair_frame: int = 20
    pair_gap: int = 4
    render_size: int = 360


@dataclass(frozen=True)
class ZooModels:
    """The zoo entries the demo starts from (``zoo/NAME``, :mod:`c3f_slam.models.zoo`): DepthNet (its
    weights are test-time trained on the held-out sequence; its ONNX file is the network
    "without TTT") and ContraFeat (its ONNX file as it is)."""

    depth: str = "c3f-depth-r18w32"
    features: str = "c3f-features-r18w32"


@dataclass(frozen=True)
class VideoConfig:
    """A user's own video (``--video``) and how it becomes a sequence folder (``ingest`` stage).

    ``path``: the video (absolute); intrinsics from ``camera`` (a camera.json, absolute) or the
    guess ``fov`` (horizontal field of view, degrees), one of the two. Frames: every k-th, k the
    smallest that keeps at most ``max_fps`` frames per second of video; at most ``max_frames`` of
    them (from the start); resized so that the longer side is at most ``max_side`` pixels (never
    enlarged).
    """

    path: str
    camera: str | None = None
    fov: float | None = None
    max_fps: float = 30.0
    max_frames: int = 600
    max_side: int = 256


@dataclass(frozen=True)
class DemoConfig:
    """All settings of one demo run (their hash decides which stages a rerun may skip).
    ``simulate`` is None for a user's video (``video``)."""

    simulate: SimulateConfig | None = field(default_factory=SimulateConfig)
    depth: DepthTrainConfig = field(default_factory=DepthTrainConfig)
    ttt: TestTimeConfig = field(default_factory=TestTimeConfig)
    features: FeatureTrainConfig = field(default_factory=FeatureTrainConfig)
    report: ReportConfig = field(default_factory=ReportConfig)
    quick: bool = False
    zoo: ZooModels | None = None  #: start from these zoo models; None: train them (``--from-scratch``)
    video: VideoConfig | None = None  #: a user's own video instead of the simulator (``--video``)

    @property
    def from_zoo(self) -> bool:
        return self.zoo is not None

    @property
    def sequence_frames(self) -> int:
        """Frames of the sequence SLAM runs on (at most, for a video): for the time estimates."""
        return self.video.max_frames if self.video else self.simulate.test_frames

    def as_dict(self) -> dict:
        return asdict(self)


def demo_config(quick: bool = False, from_scratch: bool = False) -> DemoConfig:
    """The default preset, or the ``quick`` one (shorter sequences, fewer steps); from the zoo's
    models unless ``from_scratch``. From the zoo only the held-out sequence is simulated (the
    training sequences are the zoo's) and test-time training uses the zoo model's size."""
    if not from_scratch:
        base = demo_config(quick, from_scratch=True)
        sim = replace(base.simulate, train=(), train_frames=0, size=ZOO_SIZE)
        ttt = replace(base.ttt, steps=3 if quick else ZOO_TTT_STEPS, pose_warmup_steps=1 if quick else 30)
        return replace(base, simulate=sim, ttt=ttt, zoo=ZooModels())
    if not quick:
        return DemoConfig(depth=DepthTrainConfig(lr=5e-4))
    return DemoConfig(
        simulate=SimulateConfig(train=(("seq1", 100),), train_frames=48, test_frames=40,
                                train_coverage=0.025, test_coverage=0.02),
        depth=DepthTrainConfig(steps=12, batch_size=2),
        ttt=TestTimeConfig(steps=3, batch_size=2, pose_warmup_steps=1),
        features=FeatureTrainConfig(steps=6),
        report=ReportConfig(sample_frames=3, depth_eval_stride=3, pair_frame=10, render_size=240),
        quick=True,
    )


def video_config(video: str, camera: str | None = None, fov: float | None = None, quick: bool = False) -> DemoConfig:
    """The run on a user's video: the zoo's models, test-time training of DepthNet on the video's
    frames (the demo's preset, ``quick``: 3 steps), SLAM with and without it. ``quick``: at most 24
    frames of at most 128 px (tests)."""
    base = demo_config(quick)
    frames = VideoConfig(video, camera, fov, max_frames=24, max_side=128) if quick else VideoConfig(video, camera, fov)
    return replace(base, simulate=None, video=frames)
