"""Where fusion gets a processed frame's RGB and depth back (frames are never kept in memory).

:class:`c3f_slam.fusion.tsdf.FragmentFusion` re-reads the frames of the fragments it fuses at the
end of the run (the main map, each written component), by log row. Two sources:

- :class:`SequenceFrames` (RGB-D mode): re-read ``rgb/`` and ``depth/`` files of the sequence,
  in the frame's pixel grid with the sequence's intrinsics.
- :class:`PredictedFrames` (model depth): the predicted depth cannot be re-read from the
  input, and a video cannot be re-read by frame number cheaply, so each processed frame's
  network-grid RGB (PNG) and predicted depth (float16 .npy, relative precision 1e-3) are
  written to a cache folder inside the output folder and fusion runs in the network grid with
  its intrinsics (``view.camera``: the crop + resize of the frame's camera). That is the
  resolution the depth was predicted at, so nothing is lost, and memory stays flat however
  long the video. Disk use: about 0.2 MB per processed frame at 224x224 (100 kB of depth and
  a PNG; a 54,000-frame video: about 10 GB while it runs); :meth:`PredictedFrames.close`
  removes the folder at the end of the run, whatever happens. Re-running the net instead would
  cost a second prediction per frame (one for tracking, one for the mesh) and random access into
  the video.
"""

from __future__ import annotations

import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Protocol

import cv2
import numpy as np

from c3f_slam.frames.preprocess import center_crop_resize
from c3f_slam.frames.stream import StreamFrame
from c3f_slam.io.sequence import Sequence, read_rgb
from c3f_slam.pipeline.frontend import DepthPrediction, ModelDepth

CACHE_DIR = ".depth_cache"


class FusionFrames(Protocol):
    """``K`` (3x3, pixels) of the loaded images; ``record`` a processed frame under its log
    row; ``load(row)`` -> (RGB uint8, depth float32 metres); ``close`` frees what it holds."""

    K: np.ndarray

    def record(self, row: int, frame: StreamFrame, prediction: DepthPrediction | None = None) -> None: ...

    def load(self, row: int) -> tuple[np.ndarray, np.ndarray]: ...

    def close(self) -> None: ...


class SequenceFrames:
    """RGB-D mode: frames re-read from the sequence folder (``index_of(row)`` -> frame index)."""

    def __init__(self, sequence: Sequence, index_of: Callable[[int], int], tissue: np.ndarray | None = None) -> None:
        """``tissue``: (H, W) bool tissue area; depth outside it is 0 (None: the whole frame)."""
        self.sequence = sequence
        self.index_of = index_of
        self.tissue = tissue
        self.K = sequence.camera.K

    def record(self, row: int, frame: StreamFrame, prediction: DepthPrediction | None = None) -> None:
        pass

    def load(self, row: int) -> tuple[np.ndarray, np.ndarray]:
        i = int(self.index_of(row))
        depth = self.sequence.read_depth(i)
        return self.sequence.read_rgb(i), depth if self.tissue is None else np.where(self.tissue, depth, np.float32(0))

    def close(self) -> None:
        pass


class PredictedFrames:
    """Model-depth mode: network-grid RGB + predicted depth cached on disk under ``root``
    (emptied first; removed by :meth:`close`)."""

    def __init__(self, root: str | Path, depth: ModelDepth) -> None:
        self.root = Path(root)
        self.depth = depth
        self.K = depth.view.camera.K
        shutil.rmtree(self.root, ignore_errors=True)
        self.root.mkdir(parents=True)

    def _paths(self, row: int) -> tuple[Path, Path]:
        return self.root / f"{row:08d}.png", self.root / f"{row:08d}.npy"

    def record(self, row: int, frame: StreamFrame, prediction: DepthPrediction | None = None) -> None:
        """``prediction``: the one perception made of this frame (None: predicted again)."""
        pred = prediction if prediction is not None else self.depth.predict(frame)
        pp = self.depth.model.metadata.preprocessing
        rgb, _ = center_crop_resize(frame.rgb, self.depth.camera, pp.crop, pp.size)
        rgb_path, depth_path = self._paths(row)
        if not cv2.imwrite(str(rgb_path), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)):
            raise OSError(f"could not write {rgb_path}")
        np.save(depth_path, pred.network.astype(np.float16))

    def load(self, row: int) -> tuple[np.ndarray, np.ndarray]:
        rgb_path, depth_path = self._paths(row)
        return read_rgb(rgb_path), np.load(depth_path).astype(np.float32)

    def close(self) -> None:
        shutil.rmtree(self.root, ignore_errors=True)


def fusion_frames(
    depth: object, sequence: Sequence | None, index_of: Callable[[int], int], out_dir: str | Path
) -> FusionFrames:
    """The source for the run's depth provider: :class:`PredictedFrames` (cache in
    ``out_dir``/:data:`CACHE_DIR`) for :class:`ModelDepth`, else :class:`SequenceFrames`."""
    if isinstance(depth, ModelDepth):
        return PredictedFrames(Path(out_dir) / CACHE_DIR, depth)
    if sequence is None:
        raise ValueError("depth from files needs a sequence folder")
    return SequenceFrames(sequence, index_of, getattr(depth, "tissue", None))
