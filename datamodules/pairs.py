"""Frame pairs at several frame gaps for ContraFeat (a data module over any layout with depth and poses).

A sample is a pair (t, t + g * stride) in the batch layout of :mod:`datamodules.base` with
F = 2 (``image`` (B, 2, 3, H, W), ``depth``, ``pose``, ...). Training draws the gap g for
every sample uniformly from ``sampling.gaps`` (so wide baselines are learned); validation and
test use every gap of ``sampling.eval_gaps`` deterministically (every ``eval_stride``-th pair).
"""

from __future__ import annotations

from collections.abc import Sequence as SequenceABC
from dataclasses import dataclass
from pathlib import Path

import torch
from torch.utils.data import Dataset

from c3f_core.errors import InputError
from c3f_core.settings import as_config
from datamodules.base import DEFAULT_FRAMES, DEFAULT_SPLIT, FrameSource, FrameTupleDataset, SequenceDataModule
from datamodules.config import FramesConfig, LoaderConfig, SplitConfig, TupleSamplingConfig, check_stride
from datamodules.formats import SequenceFormat, make_format


@dataclass(frozen=True)
class PairSamplingConfig:
    """The frame pairs (t, t + g * stride) of ContraFeat's samples, g a frame gap.

    Attributes:
        gaps: gaps drawn at random for each training sample (paper: wide baselines), e.g. [1, 2, 4, 8].
        eval_gaps: gaps used, all of them, for validation and test; null or empty = ``gaps``.
        eval_stride: keep every n-th pair of each gap for validation and test.
        stride: multiplies the gaps.
    """

    gaps: tuple[int, ...] = (1, 2, 4, 8)
    eval_gaps: tuple[int, ...] | None = None
    eval_stride: int = 1
    stride: int = 1

    def __post_init__(self) -> None:
        if not self.gaps or any(int(g) < 1 for g in self.gaps):
            raise InputError(f"data.sampling.gaps must be a non-empty list of integers >= 1, got {list(self.gaps)}")
        if self.eval_gaps and any(int(g) < 1 for g in self.eval_gaps):
            raise InputError(f"data.sampling.eval_gaps must be integers >= 1, got {list(self.eval_gaps)}")
        if self.eval_stride < 1:
            raise InputError(f"data.sampling.eval_stride must be >= 1, got {self.eval_stride}")
        check_stride(self.stride)
        object.__setattr__(self, "gaps", tuple(self.gaps))
        if self.eval_gaps is not None:
            object.__setattr__(self, "eval_gaps", tuple(self.eval_gaps))

    def gaps_for(self, train: bool) -> tuple[int, ...]:
        """The gaps of the training pairs, or of the validation and test pairs."""
        return self.gaps if train or not self.eval_gaps else self.eval_gaps


class GapPairDataset(Dataset):
    """Pairs (t, t + g * stride) of frames with ground truth: for training a random gap g per
    sample, for validation and test every ``eval_stride``-th pair of each evaluation gap.

    Sequences too short for a gap are left out of that gap; a gap that fits no sequence is
    dropped; no gap fitting any sequence is an InputError.
    """

    def __init__(
        self, sequences: SequenceABC[FrameSource], sampling: PairSamplingConfig, frames: FramesConfig, train: bool
    ) -> None:
        gaps, stride = sampling.gaps_for(train), sampling.stride
        every = 1 if train else sampling.eval_stride
        self.random_gap = train
        self.by_gap: dict[int, FrameTupleDataset] = {}
        for g in sorted({int(g) for g in gaps}):
            fits = [s for s in sequences if len(s) > g * stride]
            if fits:
                self.by_gap[g] = FrameTupleDataset(fits, frames, TupleSamplingConfig((0, g), stride))
        if not self.by_gap:
            longest = max((len(s) for s in sequences), default=0)
            raise InputError(
                f"no sequence is long enough for any frame gap in {list(gaps)} (longest: {longest} frames)"
            )
        self.gaps = list(self.by_gap)
        self.index = [(g, k) for g, ds in self.by_gap.items() for k in range(0, len(ds), every)]
        self.length = max(len(ds) for ds in self.by_gap.values()) if train else len(self.index)

    def __len__(self) -> int:
        return self.length

    def __getitem__(self, key: int | tuple[int, int]) -> dict:
        """``key``: an index, or (index, draw) from a keyed :class:`datamodules.resumable.ResumableSampler`
        (a training sample's gap is then ``draw``'s choice, else one drawn from torch's global RNG)."""
        idx, draw = key if isinstance(key, tuple) else (key, None)
        if self.random_gap:
            pick = int(torch.randint(len(self.gaps), (1,)).item()) if draw is None else draw % len(self.gaps)
            g = self.gaps[pick]
            ds = self.by_gap[g]
            sample = ds[min(idx * len(ds) // self.length, len(ds) - 1)]
        else:
            g, k = self.index[idx]
            sample = self.by_gap[g][k]
        sample["gap"] = g
        return sample


#: ContraFeat's defaults where they differ from the base's (frame pairs, batch 8)
DEFAULT_PAIRS, DEFAULT_PAIR_LOADER = PairSamplingConfig(), LoaderConfig(batch_size=8)


class ContraFeatDataModule(SequenceDataModule):
    """Frame pairs at several gaps from sequences with depth and poses.

    Args:
        data_dir: folder holding the sequences.
        layout: the sequences' layout, a name of :mod:`datamodules.formats`: ``c3f`` (the
            project's, default), ``uts``, ``simcol3d`` or ``c3vd``.
        layout_options: options of that layout's reader, e.g. ``{fov: 110}`` (uts),
            ``{calibration: FILE, pinhole_focal: 700}`` (c3vd).
        split: sequence names per split, or the fractions of an automatic split.
        sampling: the frame gaps of training and evaluation pairs, the evaluation stride.
        frames: centre crop, size (width, height) and specular inpainting of every frame.
        loader: batch size (default 8) and loader processes.
        min_frames: a sequence with fewer frames is an error (``c3f`` layout).

    ``split``, ``frames`` and ``loader`` are the groups of :mod:`datamodules.config`, as in
    :class:`datamodules.base.SequenceDataModule`; ``sampling`` is :class:`PairSamplingConfig`.
    """

    def __init__(
        self,
        data_dir: str,
        layout: str = "c3f",
        layout_options: dict | None = None,
        split: SplitConfig = DEFAULT_SPLIT,
        sampling: PairSamplingConfig = DEFAULT_PAIRS,
        frames: FramesConfig = DEFAULT_FRAMES,
        loader: LoaderConfig = DEFAULT_PAIR_LOADER,
        min_frames: int = 2,
    ) -> None:
        split = as_config(split, DEFAULT_SPLIT, "data.split")
        sampling = as_config(sampling, DEFAULT_PAIRS, "data.sampling")
        frames = as_config(frames, DEFAULT_FRAMES, "data.frames")
        loader = as_config(loader, DEFAULT_PAIR_LOADER, "data.loader")
        super().__init__(data_dir, split=split, sampling=TupleSamplingConfig((0, 1), sampling.stride),
                         frames=frames, loader=loader, min_frames=min_frames)
        self.pairs_config = sampling
        self.layout, self.layout_options = layout, layout_options
        self.sequence_format()  # an unknown layout or option fails here, before any data is read

    keyed_samples = True  # a training sample's gap comes from its draw (exact resume)

    def sequence_format(self) -> SequenceFormat:
        options = dict(self.layout_options or {})
        if self.layout == "c3f":
            options.setdefault("min_frames", self.min_frames)
        return make_format(self.layout, option_prefix="data.", **options)

    def make_dataset(self, paths: list[Path], train: bool) -> GapPairDataset:
        seqs = [self.open_sequence(p) for p in paths]
        missing = [s.name for s in seqs if not (s.has_depth and s.has_poses)]
        if missing:
            raise InputError(f"ContraFeat needs depth and poses; sequence {missing[0]!r} in {self.data_dir} lacks them")
        return GapPairDataset(seqs, self.pairs_config, self.frames_config, train)
