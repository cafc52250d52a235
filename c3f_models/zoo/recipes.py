"""The zoo's recipes: every model of ``zoo/`` is made by one of these, in one command
(``python -m c3f_models zoo train NAME``, :mod:`c3f_models.zoo.train`).

A recipe is a complete, frozen description: the simulator sequences it trains and validates
on (preset, seed, frames, path coverage; square frames of ``size`` pixels), the LightningCLI
config in ``configs/zoo/`` that holds the model, loss, optimiser and trainer, the number of
optimiser steps and what is exported. The held-out sequences of the zoo's evaluation
(:data:`HELD_OUT`) share no seed with any recipe, and ``seq5`` (appearance C: orange, dark,
grainy) is in none.

The second version (``-v2``) fine-tunes the first one's weights (:attr:`Recipe.init`) on
sequences of randomised looks (:attr:`SimSpec.look`: :func:`datamodules.synthetic.randomize.sample_look`,
recording effects included). The published-data recipes (:attr:`Recipe.dataset`) fine-tune the
depth model on a SimCol3D or C3VD folder given with ``zoo train NAME --data DIR``.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

#: metres of colon per frame at the paper's pace (4,500 frames over the 1.25 m presets)
PAPER_STEP = 1.25 / 4500
COLON_LENGTH = 1.25  #: metres, the presets' centreline


@dataclass(frozen=True)
class SimSpec:
    """One simulator sequence: ``python -m datamodules.synthetic generate --preset PRESET --set
    seed=SEED --set path.frames=FRAMES --set path.coverage=COVERAGE`` (``coverage``: share of the
    colon the path travels; ``step_mm`` gives the motion per frame). With ``look``, the items of
    ``sample_look(look)`` follow as more ``--set`` (a randomised appearance, folds, border, blur
    and a recording's effects); the name then ends in ``_l<look>``."""

    preset: str
    seed: int
    frames: int
    coverage: float
    look: int | None = None

    @property
    def name(self) -> str:
        return f"{self.preset}_s{self.seed}" + ("" if self.look is None else f"_l{self.look}")

    @property
    def look_items(self) -> tuple[str, ...]:
        """The simulator's ``group.field=value`` items of the look (none without one)."""
        if self.look is None:
            return ()
        from datamodules.synthetic.randomize import sample_look

        return sample_look(self.look)

    @property
    def step_mm(self) -> float:
        return 1000.0 * self.coverage * COLON_LENGTH / self.frames


def at_pace(preset: str, seed: int, frames: int, pace: float = 1.0, look: int | None = None) -> SimSpec:
    """A sequence that moves ``pace`` times the paper's distance per frame."""
    return SimSpec(preset, seed, frames, round(pace * PAPER_STEP * frames / COLON_LENGTH, 5), look)


@dataclass(frozen=True)
class Recipe:
    """How one zoo entry is made.

    Attributes:
        name: the entry's name (``zoo/NAME``; ``zoo:NAME`` on the command lines).
        kind: ``depth`` (DepthNet + PoseNet) or ``descriptors`` (ContraFeat).
        config: the LightningCLI config under ``configs/`` (model, loss, optimiser, trainer).
        train, val: the simulator sequences it trains and validates on.
        size: square frame size of the sequences, pixels.
        steps: optimiser steps.
        graphs: what the ONNX export writes (the runtime needs ``depth`` or ``descriptors``; PoseNet
            travels in the weights, for test-time training, and is exported on demand).
        summary: one line for ``zoo list`` and the card.
        deviations: how the recipe departs from the paper (the card lists them).
        limits: what the model is not known to do (the card lists them).
        quick: the few-step check of a recipe (:func:`quick`), not a trained model.
        storage: how the ONNX file stores its weights: ``float16`` (half the size, float32 compute;
            the exporter folds batch norm into convolutions, so those weights are rounded again and
            the parity check measures it) or ``float32``.
        init: the zoo entry whose weights start the fit (``model.init_weights``); None: from scratch.
        dataset: a published data set (:data:`DATASETS`) read from ``zoo train NAME --data DIR``
            instead of simulator sequences (``train`` and ``val`` empty: its data module splits).
    """

    name: str
    kind: str
    config: str
    train: tuple[SimSpec, ...]
    val: tuple[SimSpec, ...]
    size: int = 128
    steps: int = 8000
    graphs: tuple[str, ...] = ()
    summary: str = ""
    deviations: tuple[str, ...] = field(default=())
    limits: tuple[str, ...] = field(default=())
    quick: bool = False
    storage: str = "float16"
    init: str | None = None
    dataset: str | None = None

    @property
    def command(self) -> str:
        """The command that makes this entry."""
        base = self.name.removesuffix("-quick") if self.quick else self.name
        return (f"python -m c3f_models zoo train {base}" + (" --data DIR" if self.dataset else "")
                + (" --quick" if self.quick else ""))


#: the published data sets a recipe can fine-tune on: name -> (data module, title)
DATASETS = {
    "simcol3d": ("datamodules.published.SimCol3DDataModule", "SimCol3D"),
    "c3vd": ("datamodules.published.C3VDDataModule", "C3VD"),
}


#: training sequences of the zoo: appearances A (seq1, seq2) and B (seq3, seq4), insertion,
#: withdrawal and random paths, 1.6x the paper's pace (0.45 mm per frame)
TRAIN = tuple(at_pace(p, s, 400, 1.6) for p, s in (
    ("seq1", 1001), ("seq1", 1002), ("seq1", 1003), ("seq2", 1004), ("seq2", 1005),
    ("seq3", 1006), ("seq3", 1007), ("seq3", 1008), ("seq4", 1009), ("seq4", 1010)))
VAL = (at_pace("seq1", 1011, 100, 1.6), at_pace("seq3", 1012, 100, 1.6))

#: the zoo's held-out evaluation: 3 presets x 2 seeds at the paper's pace, 128 px; seq5's
#: appearance (C) is in no recipe's data
HELD_OUT = tuple(at_pace(p, s, 300) for p, s in (
    ("seq1", 2001), ("seq1", 2002), ("seq3", 2003), ("seq3", 2004), ("seq5", 2005), ("seq5", 2006)))

LIMITS = (
    "trained and evaluated on held-out sequences of the project's procedural simulator only; no patient video "
    "was measured (a depth entry's numbers on the real frames of a phantom, when measured, are under Real frames)",
    "128x128 input: the runtime resizes every frame to it (after the recorded crop)",
    "the paper's specular mask (luma > 0.9, dilated 13 px) covers a median 10-23 % of a training frame (up to "
    "36 %) on this simulator's bright near wall, not only highlights; those pixels are inpainted before the "
    "networks see them, which blurs what they can learn there (measured on seq1_s1001, seq2_s1004, seq3_s1006)",
)

DEPTH_DEVIATIONS = (
    "supervised term on the simulator's true depth (model.loss.lambda_gt_depth 1.0) during pre-training",
    "Monodepth2 loss terms during pre-training; the paper's extra terms (L_ph-extra, L_dc, outlier and "
    "specular masks) are what test-time training uses",
    "colour augmentation of the network inputs (model.augment, Monodepth2's recipe, wider brightness)",
    "ResNet18 encoders at half width (32 channels in the first stage), no deformable convolutions, "
    "no ImageNet weights (paper: ResNet50 + DCN, 224 px)",
    "128x128 input (paper 224x224); 3,500 steps of batch 8, 7 epochs of 3,980 triplets (paper: 40 epochs of "
    "batch 16); the learning rate is halved once, at epoch 6 (milestones 6, 8, 9 of a longer schedule)",
)

DEPTH_LIMITS = LIMITS + (
    "test-time training from these weights (configs/depthnet/ttt.yaml + paper_objective.yaml, 60 steps of batch 4) "
    "changes the held-out Abs Rel by -3.0 % and -8.1 % on the unseen appearance (seq5_s2005, seq5_s2006) and by "
    "+2.6 % and -1.2 % on a trained one (seq1_s2001, seq1_s2002); what it changes is the depth network's "
    "batch-norm statistics, which follow the new sequence during ttt.yaml's 30 PoseNet-only steps: once the "
    "depth's weights train at lr 1e-4 the depth goes flat within 20 steps and the guard returns a warm-up snapshot "
    "(benchmarks/results/zoo.md; docs/lab_notes/2026-12-04-zoo-ttt-variants.md)",
    "on its depth the unseen-wall estimate gets the share within 3.3 points of the truth on seven simulator cases, "
    "but not the place: the bands hidden behind tall folds are missed, and scattered cells elsewhere make up the "
    "share (docs/lab_notes/2026-12-06-slam-reprojection-refit.md, with its figure "
    "img/unseen_map_tall_folds_zoo_depth.png)",
)

DEPTH_R18W32 = Recipe(
    name="c3f-depth-r18w32", kind="depth", config="configs/zoo/c3f-depth-r18w32.yaml", train=TRAIN, val=VAL,
    steps=3500, graphs=("depth",),
    summary="DepthNet + PoseNet, half-width ResNet18, 128 px, simulator (appearances A, B)",
    deviations=DEPTH_DEVIATIONS, limits=DEPTH_LIMITS,
)

FEATURES_R18W32 = Recipe(
    name="c3f-features-r18w32", kind="descriptors", config="configs/zoo/c3f-features-r18w32.yaml", train=TRAIN,
    val=VAL, steps=1000, graphs=("descriptors",), storage="float32",
    summary="ContraFeat, FPN on a half-width ResNet18, 128-d descriptors, 128 px, simulator (appearances A, B)",
    deviations=(
        "512 dense ground-truth correspondences per training pair join the keypoint InfoNCE (model.loss.dense_points)",
        "ResNet18 at half width (32 channels in the first stage), FPN and head at 64 channels, no ImageNet weights",
        "128x128 input; 1,000 steps of 4 frame pairs (gaps 1-16 frames)",
    ),
    limits=LIMITS,
)

#: the second version's sequences: presets seq1-seq4 and seq6-seq8 (seq5 stays unseen), 2 seeds
#: each, every one with its own randomised look (look seed = sequence seed) and a recording's
#: effects, 1.6x the paper's pace as the first version; seeds 3001-3016 are in no other recipe
V2_PRESETS = ("seq1", "seq2", "seq3", "seq4", "seq6", "seq7", "seq8")
TRAIN_V2 = tuple(at_pace(p, 3001 + i, 400, 1.6, look=3001 + i) for i, p in enumerate(sorted(V2_PRESETS * 2)))
VAL_V2 = (at_pace("seq1", 3015, 100, 1.6, look=3015), at_pace("seq6", 3016, 100, 1.6, look=3016))

V2_DEVIATIONS = (
    "fine-tuned from the first version's weights (zoo:{init}); its deviations from the paper hold too",
    "randomised looks (datamodules.synthetic.randomize.sample_look, one per sequence): mucosa colour, vessels, "
    "light, folds, scope border and overlays, blur, and a real recording's effects (white balance, fall-off, "
    "noise, JPEG / mp4v, interlacing, fluid, bubbles, extra highlights); fluid and bubble pixels (covered/) are "
    "left out of the losses",
    "presets seq1-seq4 and seq6-seq8 (geometry and paths), 2 sequences of 400 frames each; seq5 in none",
)
V2_LIMITS = (
    "the held-out evaluation is the first version's (the presets' own looks, no recording effects), so the two "
    "versions compare; it does not measure the randomised looks or recording effects, and the sampled hues "
    "(4-20 degrees) reach seq5's orange, so seq5_s2005/6 are no longer strictly an unseen appearance",
)

DEPTH_V2 = Recipe(
    name="c3f-depth-r18w32-v2", kind="depth", config="configs/zoo/c3f-depth-r18w32-v2.yaml", train=TRAIN_V2,
    val=VAL_V2, steps=7000, graphs=("depth",), init=DEPTH_R18W32.name,
    summary="DepthNet + PoseNet, half-width ResNet18, 128 px, fine-tuned on randomised simulator looks "
            "with recording effects",
    deviations=(V2_DEVIATIONS[0].format(init=DEPTH_R18W32.name), *V2_DEVIATIONS[1:],
                "7,000 steps of batch 8 (about 10 epochs of 5,572 triplets) at lr 1e-4, halved at epoch 7",
                "time estimate (2 CPU cores, from the first versions' 1.14 s per depth step and 2.09 s per "
                "descriptor step): 2.2 h of fit, plus about 10 min of simulation and 2 min of evaluation; both v2 "
                "recipes together about 4.5 h"),
    limits=LIMITS + V2_LIMITS + (
        "measured against the first version (2026-12-07, docs/zoo.md): better on the phantom's real frames "
        "(Spearman 0.950 against 0.915), worse on the held-out simulator sequences (Abs Rel 0.123 against 0.094, "
        "unseen appearance 0.111 against 0.097), and in SLAM on the phantom clip its path is less smooth (jitter "
        "1.61 against 1.31, ContraFeat of the first version); the runtime's examples keep the first version",),
)

FEATURES_V2 = Recipe(
    name="c3f-features-r18w32-v2", kind="descriptors", config="configs/zoo/c3f-features-r18w32-v2.yaml",
    train=TRAIN_V2, val=VAL_V2, steps=3000, graphs=("descriptors",), storage="float32", init=FEATURES_R18W32.name,
    summary="ContraFeat, FPN on a half-width ResNet18, 128-d, 128 px, fine-tuned on randomised simulator looks "
            "with recording effects",
    deviations=(V2_DEVIATIONS[0].format(init=FEATURES_R18W32.name), *V2_DEVIATIONS[1:],
                *FEATURES_R18W32.deviations[:2],
                "3,000 steps of 4 frame pairs (gaps 1-16 frames) at a constant lr 3e-4",
                "time estimate (2 CPU cores, from the first version's 2.09 s per step): 1.75 h of fit, plus about "
                "10 min of simulation and 7 min of evaluation; both v2 recipes together about 4.5 h"),
    limits=LIMITS + V2_LIMITS,
)

PUBLISHED_LIMITS = (
    "the card's held-out numbers are the simulator's sequences (what the fine-tune kept of it), not the data "
    "set's own test split: evaluate that one separately",
    "not trained here: no copy of the data set is on this machine; the steps and time are a plan, the quick "
    "check (tests/test_zoo_recipes_published.py) runs it on a few frames written in the published layout",
    "half-width ResNet18 at low resolution, as the first version: the paper-size model (ResNet50 + DCN, 224 px) "
    "is configs/zoo/c3f-depth-r50-{dataset}-gpu.yaml, trained from scratch on a GPU",
)

DEPTH_SIMCOL3D = Recipe(
    name="c3f-depth-r18w32-simcol3d", kind="depth", config="configs/zoo/c3f-depth-r18w32-simcol3d.yaml", train=(),
    val=(), steps=3000, graphs=("depth",), init=DEPTH_R18W32.name, dataset="simcol3d",
    summary="DepthNet + PoseNet, half-width ResNet18, 128 px, fine-tuned on SimCol3D",
    deviations=(
        f"fine-tuned from zoo:{DEPTH_R18W32.name} (simulator pre-training with its deviations)",
        "SimCol3D's 475x475 frames resized to 128x128 (no crop); its release's split (misc/train_file.txt, "
        "test_file.txt; 10 % of the training sequences validate) or 10 % / 20 % of the sequences without it",
        "supervised term on SimCol3D's depth (lambda_gt_depth 1.0) with the Monodepth2 terms, as the first version",
        "3,000 steps of batch 8 at a constant lr 1e-4",
    ),
    limits=tuple(x.format(dataset="simcol3d") for x in PUBLISHED_LIMITS),
)

DEPTH_C3VD = Recipe(
    name="c3f-depth-r18w32-c3vd", kind="depth", config="configs/zoo/c3f-depth-r18w32-c3vd.yaml", train=(),
    val=(), steps=2000, graphs=("depth",), init=DEPTH_R18W32.name, dataset="c3vd",
    summary="DepthNet + PoseNet, half-width ResNet18, 160x128 px, fine-tuned on C3VD",
    deviations=(
        f"fine-tuned from zoo:{DEPTH_R18W32.name} (simulator pre-training with its deviations)",
        "C3VD's frames undistorted to its pinhole (1350x1080) and resized whole to 160x128 (the same aspect, no "
        "crop; the paper gives no crop for its print data and uses 224x224); 10 % of the sequences validate, "
        "20 % test",
        "supervised term on C3VD's registered depth (lambda_gt_depth 1.0) with the Monodepth2 terms",
        "2,000 steps of batch 8 at a constant lr 1e-4",
    ),
    limits=tuple(x.format(dataset="c3vd") for x in PUBLISHED_LIMITS) + (
        "the simulator's 128x128 held-out frames are stretched to the 160x128 input for the card's numbers",),
)

RECIPES: dict[str, Recipe] = {r.name: r for r in (DEPTH_R18W32, FEATURES_R18W32, DEPTH_V2, FEATURES_V2,
                                                    DEPTH_SIMCOL3D, DEPTH_C3VD)}

def shortened(specs: tuple[SimSpec, ...], frames: int) -> tuple[SimSpec, ...]:
    """``specs`` with ``frames`` frames each, at the same motion per frame."""
    return tuple(replace(s, frames=frames, coverage=round(s.coverage * frames / s.frames, 6)) for s in specs)


def quick(recipe: Recipe) -> Recipe:
    """A few-step version of ``recipe`` on tiny sequences (two training sequences of different
    appearance, 24 frames; one of 12 for validation; a published-data recipe keeps the folder it
    is given): checks the whole recipe in about a minute, trains nothing useful. Its card says
    so (``quick`` in the name)."""
    train = (recipe.train[0], recipe.train[min(5, len(recipe.train) - 1)]) if recipe.train else ()
    return replace(recipe, name=recipe.name + "-quick", train=shortened(train, 24),
                   val=shortened(recipe.val[:1], 12), steps=3, quick=True,
                   summary=recipe.summary + " [QUICK CHECK: 3 steps on tiny data, not a trained model]")


#: the quick recipes' held-out sequences (one trained appearance, the unseen one)
QUICK_HELD_OUT = shortened((HELD_OUT[0], HELD_OUT[4]), 16)

__all__ = ["DATASETS", "HELD_OUT", "PAPER_STEP", "QUICK_HELD_OUT", "RECIPES", "Recipe", "SimSpec", "at_pace", "quick",
           "shortened"]
