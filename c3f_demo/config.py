"""Settings of the demo (``python -m c3f_demo``): one small frozen dataclass per stage.

Lengths are metres, frame sizes pixels (square). :func:`demo_config` gives the presets: the
default and ``quick`` (a few minutes, for CI), each starting from the zoo's models (only the
test-time training on the held-out sequence trains) or, ``from_scratch``, training both
networks first.
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
    """The zoo entries the demo starts from (``zoo/NAME``, :mod:`c3f_slam.zoo`): DepthNet (its
    weights are test-time trained on the held-out sequence; its ONNX file is the network
    "without TTT") and ContraFeat (its ONNX file as it is)."""

    depth: str = "c3f-depth-r18w32"
    features: str = "c3f-features-r18w32"


@dataclass(frozen=True)
class DemoConfig:
    """All settings of one demo run (their hash decides which stages a rerun may skip)."""

    simulate: SimulateConfig = field(default_factory=SimulateConfig)
    depth: DepthTrainConfig = field(default_factory=DepthTrainConfig)
    ttt: TestTimeConfig = field(default_factory=TestTimeConfig)
    features: FeatureTrainConfig = field(default_factory=FeatureTrainConfig)
    report: ReportConfig = field(default_factory=ReportConfig)
    quick: bool = False
    zoo: ZooModels | None = None  #: start from these zoo models; None: train them (``--from-scratch``)

    @property
    def from_zoo(self) -> bool:
        return self.zoo is not None

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
