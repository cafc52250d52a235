"""Real frames for the parity check, pre-processed exactly as in training."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from c3f_core.errors import InputError
from c3f_slam.frames.preprocess import prepare_network_input
from c3f_slam.io import Sequence
from c3f_slam.models.metadata import Preprocessing


def evenly_spaced(n: int, count: int) -> np.ndarray:
    """Indices of ``min(count, n)`` evenly spaced frames of an ``n``-frame sequence (sorted, unique)."""
    return np.unique(np.linspace(0, n - 1, num=min(count, n)).round().astype(int))


def frames_from_source(source, pre: Preprocessing, count: int = 4) -> torch.Tensor:
    """(count, 3, h, w) float32 RGB in [0, 1]: ``count`` evenly spaced frames of a sequence
    (anything with ``camera``, ``len`` and ``read_rgb``), through
    :func:`c3f_slam.frames.preprocess.prepare_network_input` with ``pre``'s crop/size/inpainting."""
    n = len(source)
    if n == 0:
        raise InputError(f"{getattr(source, 'name', source)}: the sequence has no frames")
    picks = evenly_spaced(n, count)
    out = []
    for i in picks:
        rgb, _, _ = prepare_network_input(source.read_rgb(int(i)), source.camera, crop=pre.crop, size=pre.size,
                                          specular=pre.specular_inpaint, specular_threshold=pre.specular_threshold,
                                          specular_dilation_px=pre.specular_dilation_px)
        out.append(torch.from_numpy(np.ascontiguousarray(rgb)).permute(2, 0, 1).float() / 255.0)
    frames = torch.stack(out)
    if frames.shape[0] == 1:  # pose graphs need a pair
        frames = torch.cat([frames, frames.flip(-1)])
    return frames


def calibration_images(datamodule, fallback, pre: Preprocessing, count: int) -> torch.Tensor:
    """(count, 3, h, w) frames for int8 calibration: evenly spaced over the data module's training
    sequences (about ``count / sequences`` from each), else from ``fallback`` (the parity sequence)."""
    paths = []
    if datamodule is not None and hasattr(datamodule, "split") and hasattr(datamodule, "open_sequence"):
        paths = list(datamodule.split().get("train") or [])
    if not paths:
        return frames_from_source(fallback, pre, count)
    per = max(1, -(-count // len(paths)))
    frames = torch.cat([frames_from_source(datamodule.open_sequence(p), pre, per) for p in paths])
    return frames[torch.from_numpy(evenly_spaced(len(frames), count))]


def parity_source(frames: str | Path | None, datamodule) -> object:
    """The sequence the parity frames come from: ``frames`` (a sequence folder) when given,
    else the first test (then val, then train) sequence of the datamodule."""
    if frames is not None:
        path = Path(frames)
        if not path.is_dir():
            raise InputError(f"--frames: sequence folder not found: {path}")
        return Sequence(path)
    if datamodule is None or not hasattr(datamodule, "split"):
        raise InputError("--frames: give a sequence folder for the parity check "
                         "(the config has no sequence data module)")
    splits = datamodule.split()
    for name in ("test", "val", "train"):
        if splits.get(name):
            return datamodule.open_sequence(splits[name][0])
    raise InputError(f"--frames: the data module found no sequences in {datamodule.data_dir}; give a sequence folder")
