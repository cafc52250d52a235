"""Frame pairs at several frame gaps for ContraFeat (a data module over any layout with depth and poses).

A sample is a pair (t, t + g * stride) in the batch layout of :mod:`datamodules.base` with
F = 2 (``image`` (B, 2, 3, H, W), ``depth``, ``pose``, ...). Training draws the gap g for
every sample uniformly from ``gaps`` (so wide baselines are learned); validation and test
use every gap of ``eval_gaps`` deterministically (every ``eval_stride``-th pair).
"""

from __future__ import annotations

from collections.abc import Sequence as SequenceABC
from pathlib import Path

import torch
from torch.utils.data import Dataset

from c3f_slam.errors import InputError
from datamodules.base import FrameSource, FrameTupleDataset, SequenceDataModule
from datamodules.formats import SequenceFormat, make_format


class GapPairDataset(Dataset):
    """Pairs (t, t + g * stride) of frames, g from ``gaps`` (random per sample, or all in turn).

    Sequences too short for a gap are left out of that gap; a gap that fits no sequence is
    dropped; no gap fitting any sequence is an InputError.
    """

    def __init__(
        self,
        sequences: SequenceABC[FrameSource],
        gaps: SequenceABC[int],
        random_gap: bool,
        stride: int = 1,
        every: int = 1,
        **frame_kwargs,
    ) -> None:
        if not gaps or any(int(g) < 1 for g in gaps):
            raise InputError(f"gaps must be a non-empty list of integers >= 1, got {list(gaps)}")
        if every < 1:
            raise InputError(f"eval_stride must be >= 1, got {every}")
        self.random_gap = random_gap
        self.by_gap: dict[int, FrameTupleDataset] = {}
        for g in sorted({int(g) for g in gaps}):
            fits = [s for s in sequences if len(s) > g * stride]
            if fits:
                self.by_gap[g] = FrameTupleDataset(fits, frame_offsets=(0, g), stride=stride, **frame_kwargs)
        if not self.by_gap:
            longest = max((len(s) for s in sequences), default=0)
            raise InputError(
                f"no sequence is long enough for any frame gap in {list(gaps)} (longest: {longest} frames)"
            )
        self.gaps = list(self.by_gap)
        self.index = [(g, k) for g, ds in self.by_gap.items() for k in range(0, len(ds), every)]
        self.length = max(len(ds) for ds in self.by_gap.values()) if random_gap else len(self.index)

    def __len__(self) -> int:
        return self.length

    def __getitem__(self, idx: int) -> dict:
        if self.random_gap:
            g = self.gaps[int(torch.randint(len(self.gaps), (1,)).item())]
            ds = self.by_gap[g]
            sample = ds[min(idx * len(ds) // self.length, len(ds) - 1)]
        else:
            g, k = self.index[idx]
            sample = self.by_gap[g][k]
        sample["gap"] = g
        return sample


class ContraFeatDataModule(SequenceDataModule):
    """Frame pairs at several gaps from sequences with depth and poses.

    Args:
        layout: the sequences' layout, a name of :mod:`datamodules.formats`: ``c3f`` (the
            project's, default), ``uts``, ``simcol3d`` or ``c3vd``.
        layout_options: options of that layout's reader, e.g. ``{fov: 110}`` (uts),
            ``{calibration: FILE, pinhole_focal: 700}`` (c3vd).
        gaps: frame gaps drawn at random for training (paper: wide baselines), e.g. [1, 2, 4, 8].
        eval_gaps: gaps used (all of them) for validation and test (default: ``gaps``).
        eval_stride: keep every n-th pair of each gap for validation and test.
        The others are those of :class:`datamodules.base.SequenceDataModule` (``stride``
        multiplies the gaps; ``frame_offsets`` is not used).
    """

    def __init__(
        self,
        data_dir: str,
        layout: str = "c3f",
        layout_options: dict | None = None,
        gaps: list[int] = [1, 2, 4, 8],  # noqa: B006 (jsonargparse needs a literal default)
        eval_gaps: list[int] | None = None,
        eval_stride: int = 1,
        train: list[str] | None = None,
        val: list[str] | None = None,
        test: list[str] | None = None,
        val_fraction: float = 0.1,
        test_fraction: float = 0.2,
        stride: int = 1,
        crop: tuple[int, int] | None = None,
        size: tuple[int, int] | None = (224, 224),
        specular: bool = True,
        batch_size: int = 8,
        num_workers: int = 0,
        min_frames: int = 2,
    ) -> None:
        super().__init__(
            data_dir=data_dir, train=train, val=val, test=test, val_fraction=val_fraction,
            test_fraction=test_fraction, frame_offsets=[0, 1], stride=stride, crop=crop, size=size,
            specular=specular, load_depth=True, load_poses=True, batch_size=batch_size,
            num_workers=num_workers, min_frames=min_frames,
        )
        self.save_hyperparameters()
        self.sequence_format()  # an unknown layout or option fails here, before any data is read

    def sequence_format(self) -> SequenceFormat:
        hp = self.hparams
        options = dict(hp.layout_options or {})
        if hp.layout == "c3f":
            options.setdefault("min_frames", hp.min_frames)
        return make_format(hp.layout, option_prefix="data.", **options)

    def make_dataset(self, paths: list[Path], train: bool) -> GapPairDataset:
        hp = self.hparams
        seqs = [self.open_sequence(p) for p in paths]
        missing = [s.name for s in seqs if not (s.has_depth and s.has_poses)]
        if missing:
            raise InputError(f"ContraFeat needs depth and poses; sequence {missing[0]!r} in {self.data_dir} lacks them")
        gaps = hp.gaps if train or not hp.eval_gaps else hp.eval_gaps
        return GapPairDataset(
            seqs, gaps, random_gap=train, stride=hp.stride, every=1 if train else hp.eval_stride,
            crop=hp.crop, size=hp.size, specular=hp.specular, load_depth=True, load_poses=True,
        )
