"""Where the global stage keeps its keyframes' features (descriptors and 3D points).

Every keyframe stays a match candidate for the whole run (the appearance and spatial
candidates reach any of them), so its descriptors (N, D) (uint8 for SIFT, float16 for
ContraFeat) and camera-frame 3D points (N, 3) float32 metres (NaN = no depth) must be kept;
on long streams they are the largest part of the map (~5 KB per keyframe with SIFT).

:class:`KeyframeStore` keeps them either

- in RAM (``folder=None``: tests and direct use of :class:`FragmentSlam`), as before; or
- on disk (``folder`` given, :func:`c3f_slam.pipeline.run.run_slam` uses
  ``OUT/.keyframe_cache``): each keyframe's arrays are appended to one binary file
  (descriptors then points, raw C-order bytes) and only a small per-keyframe record stays in
  RAM (byte offset, count, dtype codes, descriptor width, frame index, timestamp: 34 bytes
  in one NumPy structured array). A keyframe is read back on demand with ``os.preadv``
  into fresh arrays (plain reads, not mmap, so read pages do not stay in the resident set),
  through a small LRU of recently used keyframes (recent keyframes are candidates again and
  again). The bytes are exact copies, so matching gives bit-for-bit the same results as
  with the arrays in RAM.

Either way ``store[k]`` is a :class:`FrameFeatures` with no pixel keypoints (``xy`` (0, 2)).
The on-disk folder is emptied when the store opens and removed by :meth:`KeyframeStore.close`.
Write or open failures (disk full, unwritable folder) raise :class:`InputError` with one line
naming the folder.
"""

from __future__ import annotations

import os
import shutil
from collections import OrderedDict
from pathlib import Path

import numpy as np

from c3f_core.errors import InputError
from c3f_slam.pipeline.frontend import FrameFeatures

#: the cache folder of a run, inside its output folder
CACHE_DIR = ".keyframe_cache"
#: the file in it that holds the keyframes' arrays
DATA_FILE = "keyframes.bin"
#: the (absent) pixel keypoints of a stored keyframe, shared by all of them
NO_XY = np.zeros((0, 2), np.float32)
NO_XY.flags.writeable = False

#: per keyframe in RAM (disk mode): byte offset in the data file, keypoint count, descriptor
#: width D, dtype codes (index into the store's dtype table) of descriptors and points,
#: frame index, timestamp (seconds)
RECORD = np.dtype([
    ("offset", np.int64), ("count", np.int32), ("width", np.int32), ("desc_dtype", np.uint8),
    ("point_dtype", np.uint8), ("index", np.int64), ("timestamp", np.float64),
])


def keyframe_record(kf: FrameFeatures) -> FrameFeatures:
    """What the global stage keeps of a keyframe: its descriptors and 3D points
    (:func:`c3f_slam.pipeline.frontend.match_frames` reads nothing else); the pixel keypoints
    are dropped (the shared empty (0, 2) array :data:`NO_XY`)."""
    return FrameFeatures(kf.index, kf.timestamp, NO_XY, kf.descriptors, kf.points)


class KeyframeStore:
    """Keyframe features by keyframe id (0, 1, ... in append order), in RAM or on disk (see
    the module docstring). ``len(store)``, ``store[k]`` -> :class:`FrameFeatures` (negative
    ids count from the end), :attr:`nbytes` (bytes held in RAM), :attr:`disk_bytes` (bytes of
    the data file), :attr:`timestamps` (seconds, without reading the file)."""

    def __init__(self, folder: str | Path | None = None, lru: int = 64) -> None:
        self.folder = None if folder is None else Path(folder)
        self.lru_size = max(int(lru), 0)
        self._ram: list[FrameFeatures] = []
        self._ram_bytes = 0
        self._meta = np.zeros(0, RECORD)
        self._n = 0
        self._end = 0  # bytes written to the data file
        self._dtypes: list[np.dtype] = []
        self._lru: OrderedDict[int, FrameFeatures] = OrderedDict()
        self._fd: int | None = None
        if self.folder is not None:
            self._fd = self._open(self.folder)

    # ------------------------------------------------------------------ file
    @staticmethod
    def _open(folder: Path) -> int:
        """Empty ``folder`` and open its data file for reading and writing; InputError when
        that fails."""
        try:
            shutil.rmtree(folder, ignore_errors=True)
            folder.mkdir(parents=True)
            return os.open(folder / DATA_FILE, os.O_RDWR | os.O_CREAT | os.O_TRUNC, 0o600)
        except OSError as exc:
            shutil.rmtree(folder, ignore_errors=True)
            raise InputError(f"keyframe cache {folder}: cannot create it ({exc.strerror or exc})") from None

    @property
    def on_disk(self) -> bool:
        return self.folder is not None

    def close(self) -> None:
        """Close the data file and remove the folder (idempotent). The per-keyframe records
        (:attr:`timestamps`, :attr:`disk_bytes`) stay readable; reading keyframes does not."""
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None
        self._lru.clear()
        if self.folder is not None:
            shutil.rmtree(self.folder, ignore_errors=True)

    def _write(self, data: bytes) -> int:
        """Append ``data`` to the data file; returns its byte offset."""
        if self._fd is None:
            raise InputError(f"keyframe cache {self.folder}: closed")
        offset, view = self._end, memoryview(data)
        try:
            done = 0
            while done < len(view):
                done += os.pwrite(self._fd, view[done:], offset + done)
        except OSError as exc:
            raise InputError(f"keyframe cache {self.folder}: cannot write ({exc.strerror or exc})") from None
        self._end += len(view)
        return offset

    def _read(self, k: int) -> FrameFeatures:
        """Keyframe ``k`` read back from the data file into fresh (aligned) arrays."""
        r = self._meta[k]
        n, width = int(r["count"]), int(r["width"])
        desc = np.empty((n, width), self._dtypes[r["desc_dtype"]])
        pts = np.empty((n, 3), self._dtypes[r["point_dtype"]])
        if self._fd is None:
            raise InputError(f"keyframe cache {self.folder}: closed")
        try:
            got = os.preadv(self._fd, [desc, pts], int(r["offset"]))
        except OSError as exc:
            raise InputError(f"keyframe cache {self.folder}: cannot read ({exc.strerror or exc})") from None
        if got != desc.nbytes + pts.nbytes:
            raise InputError(f"keyframe cache {self.folder}: keyframe {k} truncated ({got} of "
                             f"{desc.nbytes + pts.nbytes} bytes)")
        desc.flags.writeable = False
        pts.flags.writeable = False
        return FrameFeatures(int(r["index"]), float(r["timestamp"]), NO_XY, desc, pts)

    # ------------------------------------------------------------------ records
    def _dtype_code(self, dtype: np.dtype) -> int:
        if dtype not in self._dtypes:
            if len(self._dtypes) >= 255:
                raise ValueError("too many descriptor / point dtypes")
            self._dtypes.append(np.dtype(dtype))
        return self._dtypes.index(dtype)

    def _grow(self) -> None:
        """Room for one more record (capacity doubles; 34 bytes per keyframe)."""
        if self._n == len(self._meta):
            meta = np.zeros(max(2 * len(self._meta), 1024), RECORD)
            meta[: self._n] = self._meta[: self._n]
            self._meta = meta

    def _remember(self, k: int, kf: FrameFeatures) -> None:
        """Put keyframe ``k`` at the recent end of the LRU (evicting the oldest beyond its size)."""
        if self.lru_size == 0:
            return
        self._lru[k] = kf
        self._lru.move_to_end(k)
        while len(self._lru) > self.lru_size:
            self._lru.popitem(last=False)

    # ------------------------------------------------------------------ interface
    def append(self, kf: FrameFeatures) -> int:
        """Store keyframe ``kf`` (its descriptors and points; pixel keypoints are dropped);
        returns its id. Points must be (N, 3) with N = len(descriptors)."""
        rec = keyframe_record(kf)
        k = len(self)
        if self.folder is None:
            self._ram.append(rec)
            self._ram_bytes += rec.nbytes
            return k
        desc = np.ascontiguousarray(rec.descriptors)
        pts = np.ascontiguousarray(rec.points)
        if desc.ndim != 2 or pts.shape != (len(desc), 3):
            raise ValueError(f"keyframe {kf.index}: descriptors {desc.shape} and points {pts.shape} do not pair up")
        offset = self._write(desc.tobytes() + pts.tobytes())
        self._grow()
        self._meta[k] = (offset, len(desc), desc.shape[1], self._dtype_code(desc.dtype),
                         self._dtype_code(pts.dtype), kf.index, kf.timestamp)
        self._n += 1
        self._remember(k, rec)
        return k

    def __len__(self) -> int:
        return len(self._ram) if self.folder is None else self._n

    def __getitem__(self, k: int) -> FrameFeatures:
        n = len(self)
        if k < 0:
            k += n
        if not 0 <= k < n:
            raise IndexError(f"keyframe {k} out of range ({n} stored)")
        if self.folder is None:
            return self._ram[k]
        kf = self._lru.get(k)
        if kf is None:
            kf = self._read(k)
        self._remember(k, kf)
        return kf

    def __iter__(self):
        return (self[k] for k in range(len(self)))

    @property
    def timestamps(self) -> np.ndarray:
        """(N,) float64 seconds of the stored keyframes, in id order (no file reads)."""
        if self.folder is None:
            return np.array([k.timestamp for k in self._ram], np.float64)
        return self._meta["timestamp"][: self._n].copy()

    @property
    def frame_indices(self) -> np.ndarray:
        """(N,) int64 frame indices of the stored keyframes, in id order (no file reads)."""
        if self.folder is None:
            return np.array([k.index for k in self._ram], np.int64)
        return self._meta["index"][: self._n].copy()

    @property
    def nbytes(self) -> int:
        """Bytes held in RAM: the arrays themselves (RAM mode), or the per-keyframe records
        (at capacity) and the LRU's arrays (disk mode)."""
        if self.folder is None:
            return self._ram_bytes
        return int(self._meta.nbytes + sum(f.nbytes for f in self._lru.values()))

    @property
    def disk_bytes(self) -> int:
        """Bytes of keyframe data written to the data file (0 in RAM mode)."""
        return self._end
