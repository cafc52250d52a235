"""Frame-tuple datasets and the data-module base that every sequence loader shares.

A sample is a tuple of frames around a centre frame t, by default (t-1, t, t+1) with a
configurable stride, pre-processed as the paper does (docs/design.md, Pre-processing): centre
crop, resize (intrinsics follow), specular mask (Y > 0.9, 13-px dilation) and inpainting of the
masked pixels. A sequence of the project's layout whose camera.json names a ``tissue_mask``
(a scope's border and overlays: ``python -m datamodules.ingest`` writes one for a video) is seen as
the runtime sees it: the pixels outside the tissue area are filled with a continuation of the
tissue before the network sees them, and are left out of the losses with the specular ones. A
simulator sequence with recording effects (``covered/NNNNNN.png`` beside ``rgb/``: fluid, bubbles,
added highlights; docs/datasets.md, Recording effects) has those pixels left out too.
The settings groups (split, sampling, frames, loader) are those of :mod:`datamodules.config`.

Batch layout (``F`` = frames per sample, in ``sampling.frame_offsets`` order; t is at index
``frame_offsets.index(0)``):

====================  ===========================  =========================================
key                   shape / type                 meaning
====================  ===========================  =========================================
``image``             (B, F, 3, H, W) float32      RGB in [0, 1], specular pixels inpainted
``specular``          (B, F, 1, H, W) bool         True = left out of the losses: a
                                                  highlight, outside the tissue area, or
                                                  covered (fluid, bubbles: ``covered/``)
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
from collections.abc import MutableMapping
from collections.abc import Sequence as SequenceABC
from pathlib import Path
from typing import Protocol

import cv2
import lightning as L
import numpy as np
import torch
from torch.utils.data import DataLoader, Dataset

from c3f_core.errors import InputError
from c3f_core.settings import as_config, settings_as_dicts
from c3f_slam.camera.intrinsics import PinholeCamera
from c3f_slam.frames.preprocess import center_crop_resize, on_grid, prepare_network_input
from c3f_slam.frames.tissue import camera_mask_file, read_mask_png
from datamodules.config import FramesConfig, LoaderConfig, SplitConfig, TupleSamplingConfig
from datamodules.formats import SequenceFormat, find_sequences
from datamodules.resumable import ResumableLoader, ResumableSampler

# the defaults of the groups (frozen, so one instance serves every module)
DEFAULT_SPLIT, DEFAULT_SAMPLING, DEFAULT_FRAMES = SplitConfig(), TupleSamplingConfig(), FramesConfig()
DEFAULT_LOADER = LoaderConfig()


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


def tissue_of(seq: FrameSource) -> np.ndarray | None:
    """(H, W) bool tissue area of a sequence of the project's layout whose camera.json names a
    ``tissue_mask`` (True = tissue), else None (every pixel is tissue)."""
    root = getattr(seq, "root", None)
    path = camera_mask_file(Path(root) / "camera.json") if root is not None else None
    if path is None:
        return None
    return read_mask_png(path, seq.camera.width, seq.camera.height, f"tissue mask of sequence {seq.name!r}")


def covered_of(seq: FrameSource, i: int) -> np.ndarray | None:
    """(H, W) bool mask of frame ``i`` of a sequence with a ``covered/`` folder beside ``rgb/`` (the
    simulator's recording effects: True = fluid, bubbles or an added highlight), else None."""
    root = getattr(seq, "root", None)
    if root is None or not (Path(root) / "covered").is_dir():
        return None
    names = getattr(seq, "frame_names", None)
    path = Path(root) / "covered" / f"{names[i] if names else f'{i:06d}'}.png"
    img = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if img is None:
        raise InputError(f"sequence {seq.name!r} frame {i}: cannot read its covered mask {path}")
    mask = img > 0
    if mask.shape != (seq.camera.height, seq.camera.width):
        raise InputError(f"sequence {seq.name!r} frame {i}: covered mask is {mask.shape[1]}x{mask.shape[0]}, "
                         f"not the frame's {seq.camera.width}x{seq.camera.height}")
    return mask


class FrameTupleDataset(Dataset):
    """Tuples of frames (the centre t and t + offset * stride) from several sequences.

    Args:
        sequences: the sequences to draw from.
        frames: crop, size (width, height) and specular inpainting of every frame.
        sampling: the frame offsets around the centre and their stride.
        load_depth / load_poses: include ground truth when every sequence has it.
    """

    def __init__(
        self,
        sequences: SequenceABC[FrameSource],
        frames: FramesConfig,
        sampling: TupleSamplingConfig = DEFAULT_SAMPLING,
        load_depth: bool = True,
        load_poses: bool = True,
    ) -> None:
        self.sequences = list(sequences)
        self.offsets = sampling.offsets()
        self.frames = frames
        self.load_depth = load_depth and all(s.has_depth for s in self.sequences)
        self.load_poses = load_poses and all(s.has_poses for s in self.sequences)
        self.tissue = [tissue_of(s) for s in self.sequences]
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

    def _frame(self, seq: FrameSource, i: int, tissue: np.ndarray | None = None
               ) -> tuple[np.ndarray, np.ndarray, PinholeCamera, np.ndarray | None]:
        """Frame ``i``: network input, the mask of pixels left out of the losses, intrinsics, depth."""
        crop, size = self.frames.crop, self.frames.size
        rgb, mask, cam = prepare_network_input(seq.read_rgb(i), seq.camera, crop=crop, size=size,
                                               specular=self.frames.specular,
                                               tissue=tissue)
        if tissue is not None:
            box = seq.camera.center_crop_box(*crop) if crop is not None else (0, 0, seq.camera.width,
                                                                              seq.camera.height)
            mask = mask | ~on_grid(tissue, box, (cam.width, cam.height))
        covered = covered_of(seq, i)
        if covered is not None:  # a grid pixel over any covered frame pixel is left out
            x0, y0, w, h = seq.camera.center_crop_box(*crop) if crop is not None else (0, 0, seq.camera.width,
                                                                                       seq.camera.height)
            part = covered[y0:y0 + h, x0:x0 + w].astype(np.float32)
            if (w, h) != (cam.width, cam.height):
                part = cv2.resize(part, (cam.width, cam.height), interpolation=cv2.INTER_AREA)
            mask = mask | (part > 0)
        depth = None
        if self.load_depth:
            d = seq.read_depth(i)
            if not np.all(np.isfinite(d)):
                raise InputError(f"sequence {seq.name!r} frame {i}: depth has NaN or infinite values")
            depth, _ = center_crop_resize(d, seq.camera, crop, size, cv2.INTER_NEAREST)
        return rgb, mask, cam, depth

    def __getitem__(self, idx: int) -> dict:
        si, t = self.index[idx]
        seq = self.sequences[si]
        frames = [t + o for o in self.offsets]
        images, masks, depths = [], [], []
        cam = None
        for i in frames:
            rgb, mask, cam, depth = self._frame(seq, i, self.tissue[si])
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
    splits, loaders) is shared. The splits are given by name (``split.train``/``val``/``test``),
    or come from the data set's release (:meth:`published_split`), or are made from the sorted
    names with ``split.val_fraction``/``test_fraction``.

    Each group is a settings dataclass of :mod:`datamodules.config` (or a dict of its fields);
    in a config they are nested under ``data.init_args`` (``--data.frames.size [128, 128]``).

    Args:
        data_dir: folder holding the sequences.
        split: sequence names per split, or the fractions of an automatic split.
        sampling: the frame offsets of a sample around its centre frame, and their stride.
        frames: centre crop, size (width, height) and specular inpainting of every frame.
        loader: batch size and loader processes.
        load_depth, load_poses: put ground truth in the batch when available.
        min_frames: a sequence with fewer frames is an error (a triplet needs three).
    """

    #: the training sampler yields (index, draw) pairs (the dataset makes its random choices from the draw)
    keyed_samples: bool = False

    def __init__(
        self,
        data_dir: str,
        split: SplitConfig = DEFAULT_SPLIT,
        sampling: TupleSamplingConfig = DEFAULT_SAMPLING,
        frames: FramesConfig = DEFAULT_FRAMES,
        loader: LoaderConfig = DEFAULT_LOADER,
        load_depth: bool = True,
        load_poses: bool = True,
        min_frames: int = 3,
    ) -> None:
        super().__init__()
        split = as_config(split, DEFAULT_SPLIT, "data.split")
        sampling = as_config(sampling, DEFAULT_SAMPLING, "data.sampling")
        frames = as_config(frames, DEFAULT_FRAMES, "data.frames")
        loader = as_config(loader, DEFAULT_LOADER, "data.loader")
        self.save_hyperparameters()
        self.data_dir = Path(data_dir)
        self.split_config, self.sampling_config, self.frames_config = split, sampling, frames
        self.loader_config = loader
        self.load_depth, self.load_poses, self.min_frames = load_depth, load_poses, min_frames
        self.datasets: dict[str, FrameTupleDataset] = {}

    def _set_hparams(self, hp: MutableMapping) -> None:
        """Settings groups (dataclasses) saved as dicts, as LightningCLI saves them."""
        super()._set_hparams(settings_as_dicts(hp) if isinstance(hp, MutableMapping) else hp)

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
        set's published split (its train part shared out by ``split.val_fraction``), else the
        fractions over the sorted names."""
        found = self._sequences()
        cfg = self.split_config
        given = cfg.names()
        if all(v is None for v in given.values()):
            published = self.published_split()
            if published:
                known = {k: [n for n in names if n in found] for k, names in published.items()}
                train, val, _ = split_names(known.get("train", []), cfg.val_fraction, 0.0)
                given = {"train": train, "val": val, "test": known.get("test", [])}
        if any(v is not None for v in given.values()):
            out = {}
            for k, names in given.items():
                names = names or []
                unknown = [n for n in names if n not in found]
                if unknown:
                    shown = ", ".join(list(found)[:5]) + (", ..." if len(found) > 5 else "")
                    raise InputError(
                        f"data.split.{k}: unknown sequence {unknown[0]!r} in {self.data_dir} (found: {shown})"
                    )
                out[k] = [found[n] for n in names]
            return out
        tr, va, te = split_names(list(found), cfg.val_fraction, cfg.test_fraction)
        return {"train": [found[n] for n in tr], "val": [found[n] for n in va], "test": [found[n] for n in te]}

    def make_dataset(self, paths: list[Path], train: bool) -> FrameTupleDataset:
        seqs = [self.open_sequence(p) for p in paths]
        return FrameTupleDataset(seqs, self.frames_config, self.sampling_config, self.load_depth, self.load_poses)

    def setup(self, stage: str | None = None) -> None:
        splits = self.split()
        wanted = {"fit": ("train", "val"), "validate": ("val",), "test": ("test",), "predict": ("test",)}
        for k in wanted.get(stage, ("train", "val", "test")) if stage else ("train", "val", "test"):
            if k not in self.datasets and splits[k]:
                self.datasets[k] = self.make_dataset(splits[k], train=(k == "train"))

    # ----------------------------------------------------------- loaders
    def _loader(self, split: str, shuffle: bool) -> DataLoader:
        """The loader of ``split``: training over a :class:`ResumableSampler` (order from the run's
        seed and the epoch; a checkpoint keeps its position; under DDP this process's share), the
        others in order (under DDP Lightning shares them out). No loader draws from the global RNG
        (each has its own generator for its processes' seeds)."""
        if split not in self.datasets:
            raise InputError(
                f"no {split} sequences in {self.data_dir} (set data.split.{split} or the split fractions)"
            )
        dataset, workers = self.datasets[split], self.loader_config.num_workers
        options = {"batch_size": self.loader_config.batch_size, "num_workers": workers,
                   "persistent_workers": workers > 0, "drop_last": False}
        seed = torch.initial_seed()  # the run's seed (seed_everything), else this process's random one
        if split == "train":
            trainer = getattr(self, "trainer", None)  # with DDP: this process's share of each epoch
            replicas, rank = (trainer.world_size, trainer.global_rank) if trainer is not None else (1, 0)
            sampler = ResumableSampler(len(dataset), seed, shuffle, keyed=self.keyed_samples,
                                       epoch_of=lambda: self._train_progress()[0], replicas=replicas, rank=rank)
            return ResumableLoader(dataset, sampler, self._train_progress, **options)
        return DataLoader(dataset, shuffle=False, generator=torch.Generator().manual_seed(seed), **options)

    def _train_progress(self) -> tuple[int, int]:
        """(epoch, batches of it done) as the attached trainer counts them, a complete epoch as the
        next one's start; (0, 0) without a trainer."""
        trainer = getattr(self, "trainer", None)
        if trainer is None:
            return 0, 0
        epoch, done = trainer.current_epoch, trainer.fit_loop.epoch_loop.batch_progress.current.processed
        return (epoch + 1, 0) if done >= trainer.num_training_batches else (epoch, done)

    def train_dataloader(self) -> DataLoader:
        return self._loader("train", shuffle=True)

    def val_dataloader(self) -> DataLoader | list:
        return self._loader("val", shuffle=False) if "val" in self.datasets else []

    def test_dataloader(self) -> DataLoader:
        return self._loader("test", shuffle=False)

    def predict_dataloader(self) -> DataLoader:
        return self._loader("test", shuffle=False)
