"""Frame-tuple datasets and the data-module base that every sequence loader shares.

A sample is a tuple of frames around a centre frame t, by default (t-1, t, t+1) with a
configurable stride, pre-processed as SPEC §2 says: centre crop, resize (intrinsics
follow), specular mask (Y > 0.9, 13-px dilation) and inpainting of the masked pixels.

Batch layout (``F`` = frames per sample, in ``frame_offsets`` order; t is at index
``frame_offsets.index(0)``):

====================  ===========================  =========================================
key                   shape / type                 meaning
====================  ===========================  =========================================
``image``             (B, F, 3, H, W) float32      RGB in [0, 1], specular pixels inpainted
``specular``          (B, F, 1, H, W) bool         specular mask (True = highlight)
``K``                 (B, 3, 3) float32            intrinsics of the resized frames, pixels
``depth``             (B, F, 1, H, W) float32      ground-truth depth, metres, 0 = none (opt.)
``pose``              (B, F, 4, 4) float32         ground-truth camera-to-world, metres (opt.)
``frame_index``       (B, F) int64                 frame numbers in the sequence
``sequence``          list[str]                    sequence names
====================  ===========================  =========================================

``depth`` and ``pose`` are present when every sequence of the split has them.
"""

from __future__ import annotations

import math
from collections.abc import Sequence as SequenceABC
from pathlib import Path
from typing import Protocol

import cv2
import lightning as L
import numpy as np
import torch
from torch.utils.data import DataLoader, Dataset

from c3f_slam.camera import PinholeCamera
from c3f_slam.errors import InputError
from c3f_slam.preprocess import center_crop_resize, prepare_network_input
from datamodules.formats import SequenceFormat, find_sequences


class FrameSource(Protocol):
    """What a data set's sequence reader provides (``c3f_slam.io.Sequence`` is one)."""

    camera: PinholeCamera

    @property
    def name(self) -> str: ...
    @property
    def has_depth(self) -> bool: ...
    @property
    def has_poses(self) -> bool: ...
    def __len__(self) -> int: ...
    def read_rgb(self, i: int) -> np.ndarray: ...
    def read_depth(self, i: int) -> np.ndarray: ...
    def pose(self, i: int) -> np.ndarray: ...


class FrameTupleDataset(Dataset):
    """Tuples of frames (centre t plus ``frame_offsets`` x ``stride``) from several sequences.

    Args:
        sequences: the sequences to draw from.
        frame_offsets: offsets of the frames relative to the centre, e.g. (-1, 0, 1).
        stride: multiplies the offsets (frame gap between neighbours).
        crop: centre crop (width, height) applied first, or None.
        size: output (width, height), or None to keep the (cropped) size.
        specular: compute the specular mask and inpaint the masked pixels.
        load_depth / load_poses: include ground truth when every sequence has it.
    """

    def __init__(
        self,
        sequences: SequenceABC[FrameSource],
        frame_offsets: SequenceABC[int] = (-1, 0, 1),
        stride: int = 1,
        crop: tuple[int, int] | None = None,
        size: tuple[int, int] | None = None,
        specular: bool = True,
        load_depth: bool = True,
        load_poses: bool = True,
    ) -> None:
        if stride < 1:
            raise InputError(f"stride must be >= 1, got {stride}")
        if 0 not in frame_offsets:
            raise InputError(f"frame_offsets must contain 0 (the centre frame), got {list(frame_offsets)}")
        self.sequences = list(sequences)
        self.offsets = [int(o) * stride for o in frame_offsets]
        self.crop = tuple(crop) if crop is not None else None
        self.size = tuple(size) if size is not None else None
        self.specular = specular
        self.load_depth = load_depth and all(s.has_depth for s in self.sequences)
        self.load_poses = load_poses and all(s.has_poses for s in self.sequences)
        span = max(self.offsets) - min(self.offsets)
        self.index: list[tuple[int, int]] = []
        for si, seq in enumerate(self.sequences):
            if len(seq) <= span:
                raise InputError(
                    f"sequence {seq.name!r} has {len(seq)} frames; a tuple with offsets "
                    f"{self.offsets} needs at least {span + 1}"
                )
            lo, hi = -min(self.offsets), len(seq) - max(self.offsets)
            self.index.extend((si, t) for t in range(lo, hi))

    def __len__(self) -> int:
        return len(self.index)

    def _frame(self, seq: FrameSource, i: int) -> tuple[np.ndarray, np.ndarray, PinholeCamera, np.ndarray | None]:
        rgb, mask, cam = prepare_network_input(seq.read_rgb(i), seq.camera, self.crop, self.size, self.specular)
        depth = None
        if self.load_depth:
            d = seq.read_depth(i)
            if not np.all(np.isfinite(d)):
                raise InputError(f"sequence {seq.name!r} frame {i}: depth has NaN or infinite values")
            depth, _ = center_crop_resize(d, seq.camera, self.crop, self.size, cv2.INTER_NEAREST)
        return rgb, mask, cam, depth

    def __getitem__(self, idx: int) -> dict:
        si, t = self.index[idx]
        seq = self.sequences[si]
        frames = [t + o for o in self.offsets]
        images, masks, depths = [], [], []
        cam = None
        for i in frames:
            rgb, mask, cam, depth = self._frame(seq, i)
            images.append(torch.from_numpy(rgb).permute(2, 0, 1).float() / 255.0)
            masks.append(torch.from_numpy(mask)[None])
            if depth is not None:
                depths.append(torch.from_numpy(np.ascontiguousarray(depth, dtype=np.float32))[None])
        sample = {
            "image": torch.stack(images),
            "specular": torch.stack(masks),
            "K": torch.from_numpy(cam.K.astype(np.float32)),
            "frame_index": torch.tensor(frames, dtype=torch.int64),
            "sequence": seq.name,
        }
        if self.load_depth:
            sample["depth"] = torch.stack(depths)
        if self.load_poses:
            sample["pose"] = torch.from_numpy(np.stack([seq.pose(i) for i in frames]).astype(np.float32))
        return sample


def split_names(
    names: SequenceABC[str], val_fraction: float, test_fraction: float
) -> tuple[list[str], list[str], list[str]]:
    """Deterministic split of sorted sequence names into whole-sequence train/val/test sets.

    The last names go to test, the ones before them to val; each non-zero fraction gets at
    least one sequence while at least one is left for training.
    """
    names = sorted(names)
    n = len(names)
    n_test = math.ceil(n * test_fraction) if test_fraction > 0 else 0
    n_val = math.ceil(n * val_fraction) if val_fraction > 0 else 0
    while n_test + n_val >= n and (n_test or n_val):
        if n_val >= n_test and n_val:
            n_val -= 1
        else:
            n_test -= 1
    train = names[: n - n_val - n_test]
    val = names[n - n_val - n_test : n - n_test]
    test = names[n - n_test :]
    return train, val, test


class SequenceDataModule(L.LightningDataModule):
    """Base data module over a folder of sequences, split by whole sequence.

    Subclasses say which layout their sequences have (:meth:`sequence_format`, one of
    :mod:`datamodules.formats`); everything else (finding sequences, tuples, pre-processing,
    splits, loaders) is shared. The splits are given by name (``train``/``val``/``test``), or
    come from the data set's release (:meth:`published_split`), or are made from the sorted
    names with ``val_fraction``/``test_fraction``.

    Args:
        data_dir: folder holding the sequences.
        train, val, test: sequence names per split (None = automatic split).
        val_fraction, test_fraction: shares of sequences for the automatic split.
        frame_offsets, stride, crop, size, specular: see :class:`FrameTupleDataset`;
            ``crop`` and ``size`` are (width, height).
        load_depth, load_poses: put ground truth in the batch when available.
        batch_size, num_workers: data loader settings.
        min_frames: a sequence with fewer frames is an error (a triplet needs three).
    """

    def __init__(
        self,
        data_dir: str,
        train: list[str] | None = None,
        val: list[str] | None = None,
        test: list[str] | None = None,
        val_fraction: float = 0.1,
        test_fraction: float = 0.2,
        frame_offsets: list[int] = [-1, 0, 1],  # noqa: B006 (jsonargparse needs a literal default)
        stride: int = 1,
        crop: tuple[int, int] | None = None,
        size: tuple[int, int] | None = (224, 224),
        specular: bool = True,
        load_depth: bool = True,
        load_poses: bool = True,
        batch_size: int = 16,
        num_workers: int = 0,
        min_frames: int = 3,
    ) -> None:
        super().__init__()
        self.save_hyperparameters()
        self.data_dir = Path(data_dir)
        self.datasets: dict[str, FrameTupleDataset] = {}

    # ----------------------------------------------------------- for subclasses
    def sequence_format(self) -> SequenceFormat:
        """The layout of the sequences under ``data_dir`` (:mod:`datamodules.formats`)."""
        raise NotImplementedError(f"{type(self).__name__} must implement sequence_format()")

    def published_split(self) -> dict[str, list[str]] | None:
        """The data set's own train/test lists (names), used when no split is configured (and
        only the sequences found under ``data_dir`` of them)."""
        return self.sequence_format().published_split(self.data_dir)

    def find_sequences(self) -> list[Path]:
        """Paths of all sequences under ``data_dir``."""
        return list(self._sequences().values())

    def open_sequence(self, path: Path) -> FrameSource:
        """Open one sequence for reading."""
        return self.sequence_format().open(path)

    def _sequences(self) -> dict[str, Path]:
        if not self.data_dir.is_dir():
            raise InputError(f"data.data_dir: folder not found: {self.data_dir}")
        try:
            return find_sequences(self.sequence_format(), self.data_dir)
        except InputError as exc:
            raise InputError(f"data.data_dir: {exc}") from None

    # ----------------------------------------------------------- splits
    def split(self) -> dict[str, list[Path]]:
        """Sequence paths of each split (train/val/test): the configured names, else the data
        set's published split (its train part shared out by ``val_fraction``), else the
        fractions over the sorted names."""
        found = self._sequences()
        hp = self.hparams
        given = {"train": hp.train, "val": hp.val, "test": hp.test}
        if all(v is None for v in given.values()):
            published = self.published_split()
            if published:
                known = {k: [n for n in names if n in found] for k, names in published.items()}
                train, val, _ = split_names(known.get("train", []), hp.val_fraction, 0.0)
                given = {"train": train, "val": val, "test": known.get("test", [])}
        if any(v is not None for v in given.values()):
            out = {}
            for k, names in given.items():
                names = names or []
                unknown = [n for n in names if n not in found]
                if unknown:
                    shown = ", ".join(list(found)[:5]) + (", ..." if len(found) > 5 else "")
                    raise InputError(f"data.{k}: unknown sequence {unknown[0]!r} in {self.data_dir} (found: {shown})")
                out[k] = [found[n] for n in names]
            return out
        tr, va, te = split_names(list(found), hp.val_fraction, hp.test_fraction)
        return {"train": [found[n] for n in tr], "val": [found[n] for n in va], "test": [found[n] for n in te]}

    def make_dataset(self, paths: list[Path], train: bool) -> FrameTupleDataset:
        hp = self.hparams
        seqs = [self.open_sequence(p) for p in paths]
        return FrameTupleDataset(
            seqs,
            frame_offsets=hp.frame_offsets,
            stride=hp.stride,
            crop=hp.crop,
            size=hp.size,
            specular=hp.specular,
            load_depth=hp.load_depth,
            load_poses=hp.load_poses,
        )

    def setup(self, stage: str | None = None) -> None:
        splits = self.split()
        wanted = {"fit": ("train", "val"), "validate": ("val",), "test": ("test",), "predict": ("test",)}
        for k in wanted.get(stage, ("train", "val", "test")) if stage else ("train", "val", "test"):
            if k not in self.datasets and splits[k]:
                self.datasets[k] = self.make_dataset(splits[k], train=(k == "train"))

    # ----------------------------------------------------------- loaders
    def _loader(self, split: str, shuffle: bool) -> DataLoader:
        if split not in self.datasets:
            raise InputError(f"no {split} sequences in {self.data_dir} (set data.{split} or the split fractions)")
        return DataLoader(
            self.datasets[split],
            batch_size=self.hparams.batch_size,
            shuffle=shuffle,
            num_workers=self.hparams.num_workers,
            persistent_workers=self.hparams.num_workers > 0,
            drop_last=False,
        )

    def train_dataloader(self) -> DataLoader:
        return self._loader("train", shuffle=True)

    def val_dataloader(self) -> DataLoader | list:
        return self._loader("val", shuffle=False) if "val" in self.datasets else []

    def test_dataloader(self) -> DataLoader:
        return self._loader("test", shuffle=False)

    def predict_dataloader(self) -> DataLoader:
        return self._loader("test", shuffle=False)
