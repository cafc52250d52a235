"""Settings of the demo (``python -m c3f_demo``): one small frozen dataclass per stage, the tree
:class:`DemoConfig`, its presets (:data:`PRESETS`, complete instances) and its
:class:`~c3f_core.settings_cli.SettingsSpec` (:data:`DEMO_SETTINGS`: ``--preset``, ``--config``,
``--set part.field=value``, ``--print-config``).

Lengths are metres, frame sizes pixels (square). Presets: ``default`` and ``quick`` (a few
minutes, for CI) start from the zoo's models (only the test-time training on the held-out
sequence trains); ``from-scratch`` and ``quick-from-scratch`` train both networks first.
:func:`on_video` turns a preset into the run on a user's own video (``--video``): no simulator,
the video's frames instead of the held-out sequence, no ground truth.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, replace
from types import MappingProxyType

from c3f_core.errors import InputError
from c3f_core.settings_cli import SettingsSpec

ZOO_SIZE = 128  #: frame size of the zoo models (pixels)
ZOO_TTT_STEPS = 60  #: test-time training steps from the zoo weights (the paper's objective)


def _at_least(group: str, obj: object, low: float, *names: str) -> None:
    """InputError naming ``group.name`` for the first of ``names`` below ``low`` (None passes)."""
    for name in names:
        value = getattr(obj, name)
        if value is not None and value < low:
            raise InputError(f"{group}.{name} must be >= {low}, got {value}")


@dataclass(frozen=True)
class SimulateConfig:
    """Simulator sequences (``python -m datamodules.synthetic generate``).

    ``coverage``: share of the colon each path travels (``path.coverage``); at ``frames`` frames
    this sets the motion per frame (docs/datasets.md, Speed per frame).
    """

    train: tuple[tuple[str, int], ...] = (("seq1", 100), ("seq3", 101))  #: (preset, seed) of each training sequence
    test: tuple[str, int] = ("seq1", 200)  #: (preset, seed) of the held-out sequence
    train_frames: int = 200  #: frames of each training sequence
    test_frames: int = 150  #: frames of the held-out sequence
    size: int = 128  #: frame size (pixels)
    train_coverage: float = 0.10  #: share of the colon a training path travels
    test_coverage: float = 0.075  #: share of the colon the held-out path travels

    def __post_init__(self) -> None:
        _at_least("simulate", self, 0, "train_frames")
        _at_least("simulate", self, 2, "test_frames")
        _at_least("simulate", self, 16, "size")
        for name in ("train_coverage", "test_coverage"):
            if not 0 < getattr(self, name) <= 1:
                raise InputError(f"simulate.{name} must be in (0, 1], got {getattr(self, name)}")


@dataclass(frozen=True)
class DepthTrainConfig:
    """DepthNet training (``configs/depthnet/small.yaml`` + the Monodepth2 override)."""

    steps: int = 300  #: optimiser steps
    size: int = 64  #: frame size (pixels)
    batch_size: int = 4
    #: weight of the supervised term on the simulator's true depth (``model.loss.lambda_gt_depth``;
    #: 0 = the paper's self-supervised objective only)
    lambda_gt_depth: float = 1.0
    #: keep C3Fusion's extra terms (L_ph-extra, L_dc, outlier and specular masks); they triple the cost per step
    paper_extras: bool = False
    seed: int = 7
    lr: float | None = None  #: AdamW learning rate (none: the model config's, 1e-4)

    def __post_init__(self) -> None:
        _at_least("depth", self, 0, "steps", "lambda_gt_depth", "lr")
        _at_least("depth", self, 16, "size")
        _at_least("depth", self, 1, "batch_size")


@dataclass(frozen=True)
class TestTimeConfig:
    """Self-supervised test-time training of DepthNet on the held-out sequence (``configs/depthnet/ttt.yaml``).

    After the pre-training, no ground truth; same frame size and loss terms as the pre-training.
    """

    steps: int = 60  #: optimiser steps; 0: off, SLAM uses the pre-trained network
    batch_size: int = 4
    lr: float = 1e-4  #: AdamW learning rate
    seed: int = 7
    pose_warmup_steps: int = 30  #: the first steps train PoseNet alone (``model.pose_warmup_steps``)

    def __post_init__(self) -> None:
        _at_least("ttt", self, 0, "steps", "lr", "pose_warmup_steps")
        _at_least("ttt", self, 1, "batch_size")


@dataclass(frozen=True)
class FeatureTrainConfig:
    """ContraFeat training (``configs/contrafeat/small.yaml``)."""

    steps: int = 80  #: optimiser steps
    size: int = 128  #: frame size (pixels)
    batch_size: int = 2
    seed: int = 7

    def __post_init__(self) -> None:
        _at_least("features", self, 0, "steps")
        _at_least("features", self, 16, "size")
        _at_least("features", self, 1, "batch_size")


@dataclass(frozen=True)
class ReportConfig:
    """What the report shows."""

    sample_frames: int = 4  #: frames of the held-out sequence shown with their depth
    depth_eval_stride: int = 2  #: every k-th frame enters the depth metrics
    pair_frame: int = 20  #: first frame i of the match pair (i, i + pair_gap)
    pair_gap: int = 4  #: frames between the two of the match pair
    render_size: int = 360  #: mesh renders' size (pixels)

    def __post_init__(self) -> None:
        _at_least("report", self, 0, "pair_frame")
        _at_least("report", self, 1, "sample_frames", "depth_eval_stride", "pair_gap")
        _at_least("report", self, 16, "render_size")


@dataclass(frozen=True)
class ZooModels:
    """The zoo entries the demo starts from (``zoo/NAME``, c3f_slam.models.zoo).

    DepthNet: its weights are test-time trained on the held-out sequence, its ONNX file is the
    network "without TTT"; ContraFeat: its ONNX file as it is.
    """

    depth: str = "c3f-depth-r18w32"  #: DepthNet zoo entry
    features: str = "c3f-features-r18w32"  #: ContraFeat zoo entry


@dataclass(frozen=True)
class VideoConfig:
    """A user's own video (``--video``) and how it becomes a sequence folder (``ingest`` stage).

    Frames: every k-th, k the smallest that keeps at most ``max_fps`` frames per second of video;
    at most ``max_frames`` of them (from the start); resized so that the longer side is at most
    ``max_side`` pixels (never enlarged).
    """

    path: str = ""  #: the video (absolute; --video)
    camera: str | None = None  #: its camera.json (absolute; --camera), or none
    fov: float | None = None  #: else the guess of its horizontal field of view (degrees; --fov)
    max_fps: float = 30.0  #: frames per second of video kept, at most
    max_frames: int = 600  #: frames kept, at most
    max_side: int = 256  #: longer side of the frames (pixels), at most

    def __post_init__(self) -> None:
        _at_least("video", self, 1, "max_frames")
        _at_least("video", self, 16, "max_side")
        if self.max_fps <= 0 or (self.fov is not None and not 0 < self.fov < 180):
            bad = "max_fps must be > 0" if self.max_fps <= 0 else "fov must be in (0, 180) degrees"
            raise InputError(f"video.{bad}, got {self.max_fps if self.max_fps <= 0 else self.fov}")


@dataclass(frozen=True)
class DemoConfig:
    """All settings of one demo run (their hash decides which stages a rerun may skip)."""

    simulate: SimulateConfig | None = field(default_factory=SimulateConfig)  #: none on a user's video
    depth: DepthTrainConfig = field(default_factory=DepthTrainConfig)
    ttt: TestTimeConfig = field(default_factory=TestTimeConfig)
    features: FeatureTrainConfig = field(default_factory=FeatureTrainConfig)
    report: ReportConfig = field(default_factory=ReportConfig)
    quick: bool = False  #: the quick presets (CI size)
    zoo: ZooModels | None = None  #: start from these zoo models; none: train them (the from-scratch presets)
    video: VideoConfig | None = None  #: a user's own video instead of the simulator (``--video``)

    def __post_init__(self) -> None:
        if self.video is None:
            if self.simulate is None:
                raise InputError("simulate: none needs a video (--video FILE)")
            return
        if not self.video.path:
            raise InputError("video.path: no video given (--video FILE)")
        if self.simulate is not None:
            raise InputError("simulate: a run on a video (--video) has no simulator; set simulate=none")
        if self.zoo is None:
            raise InputError("zoo: a run on a video (--video) starts from the zoo's models, "
                             "not with the from-scratch presets")

    @property
    def from_zoo(self) -> bool:
        return self.zoo is not None

    @property
    def sequence_frames(self) -> int:
        """Frames of the sequence SLAM runs on (at most, for a video): for the time estimates."""
        return self.video.max_frames if self.video else self.simulate.test_frames

    def as_dict(self) -> dict:
        return asdict(self)


#: what the two quick presets share: fewer steps in every stage, a smaller report
QUICK_STAGES = {
    "depth": DepthTrainConfig(steps=12, batch_size=2),
    "ttt": TestTimeConfig(steps=3, batch_size=2, pose_warmup_steps=1),
    "features": FeatureTrainConfig(steps=6),
    "report": ReportConfig(sample_frames=3, depth_eval_stride=3, pair_frame=10, render_size=240),
    "quick": True,
}

#: the presets by name (read-only), complete trees (fields not named: the dataclasses' defaults).
#: From the zoo only the held-out sequence is simulated (the training sequences are the zoo's) at
#: the zoo model's frame size; the quick ones have shorter sequences and fewer steps.
PRESETS: MappingProxyType[str, DemoConfig] = MappingProxyType({
    "default": DemoConfig(
        simulate=SimulateConfig(train=(), train_frames=0, size=ZOO_SIZE),
        depth=DepthTrainConfig(lr=5e-4),
        ttt=TestTimeConfig(steps=ZOO_TTT_STEPS, pose_warmup_steps=30),
        zoo=ZooModels(),
    ),
    "quick": DemoConfig(
        simulate=SimulateConfig(train=(), train_frames=0, test_frames=40, size=ZOO_SIZE, train_coverage=0.025,
                                test_coverage=0.02),
        **QUICK_STAGES,
        zoo=ZooModels(),
    ),
    "from-scratch": DemoConfig(
        depth=DepthTrainConfig(lr=5e-4),
    ),
    "quick-from-scratch": DemoConfig(
        simulate=SimulateConfig(train=(("seq1", 100),), train_frames=48, test_frames=40, train_coverage=0.025,
                                test_coverage=0.02),
        **QUICK_STAGES,
    ),
})

#: the quick presets' frames of a user's video (tests): at most 24 frames of at most 128 px
QUICK_VIDEO = dict(max_frames=24, max_side=128)

#: the demo's settings: its presets, the state file's key that replays a run, the command
DEMO_SETTINGS: SettingsSpec[DemoConfig] = SettingsSpec(
    presets={name: (lambda tree=tree: tree) for name, tree in PRESETS.items()}, default="default",
    record_key="config", usage="python -m c3f_demo --out DIR --config THIS_FILE")


def preset_name(quick: bool = False, from_scratch: bool = False) -> str:
    """The preset ``--quick`` / ``--from-scratch`` stand for."""
    return "-".join(["quick"] * quick + ["from-scratch"] * from_scratch) or "default"


def demo_config(quick: bool = False, from_scratch: bool = False) -> DemoConfig:
    """The preset of ``quick`` / ``from_scratch`` (:data:`PRESETS`)."""
    return PRESETS[preset_name(quick, from_scratch)]


def on_video(cfg: DemoConfig, video: str, camera: str | None = None, fov: float | None = None) -> DemoConfig:
    """``cfg`` run on a user's video: no simulator, its frames (the quick presets: :data:`QUICK_VIDEO`),
    test-time training of the zoo's DepthNet on them, SLAM with and without it."""
    return replace(cfg, simulate=None, video=VideoConfig(video, camera, fov, **(QUICK_VIDEO if cfg.quick else {})))


def video_config(video: str, camera: str | None = None, fov: float | None = None, quick: bool = False) -> DemoConfig:
    """The preset ``default`` (``quick``: ``quick``) on a user's video (:func:`on_video`)."""
    return on_video(demo_config(quick), video, camera, fov)
