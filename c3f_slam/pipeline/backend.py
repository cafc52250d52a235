"""What the run loop needs from a SLAM back-end (:class:`SlamBackend`) and its map
(:class:`SlamMap`), and the frame log both maps keep (:class:`FrameLog`).

Two back-ends implement the protocol: :class:`c3f_slam.pipeline.slam.FragmentSlam` (the
full system, holding a :class:`~c3f_slam.pipeline.fragment_map.FragmentMap`) and
:class:`c3f_slam.pipeline.odometry.OdometrySlam` (the baseline, holding an
:class:`~c3f_slam.pipeline.odometry.OdometryMap`). Poses are camera-to-world 4x4 matrices in
metres; a frame is addressed by its log row (one row per streamed frame, processed or
skipped, in stream order).
"""

from __future__ import annotations

from array import array
from pathlib import Path
from typing import Protocol

import numpy as np

from c3f_slam.config import SlamConfig
from c3f_slam.io.run_outputs import KeyframeGraph
from c3f_slam.pipeline.components import MapComponent
from c3f_slam.pipeline.frame_step import FrameDecision, FrameInput
from c3f_slam.pipeline.timings import Timings


class FrameLog:
    """Per streamed frame: timestamp, fragment id (-1 = not placed), local index and, once
    its fragment is closed (:meth:`settle`), the global node the frame hangs off (-1 before)
    and its node-from-frame pose (4x4 float64, row-major). Compact arrays, no objects."""

    _UNSET = array("d", bytes(8 * 16))

    def __init__(self) -> None:
        self.index = array("q")
        self.stamp = array("d")
        self.fragment = array("q")
        self.local = array("q")
        self.node = array("q")
        self.rel = array("d")

    def append(self, index: int, stamp: float, fragment: int = -1, local: int = -1) -> None:
        self.index.append(index)
        self.stamp.append(stamp)
        self.fragment.append(fragment)
        self.local.append(local)
        self.node.append(-1)
        self.rel.extend(self._UNSET)

    def settle(self, row0: int, node: int, poses: np.ndarray, rows: list[int] | None = None) -> None:
        """A closed fragment's frames, in order, hang off ``node`` with node-from-frame ``poses``
        (n, 4, 4): rows ``row0 ..``, or ``rows`` where skipped frames lie between them."""
        n = len(poses)
        if rows is not None and rows[-1] - rows[0] != n - 1:  # not one run of rows
            if len(rows) != n:
                raise ValueError(f"{len(rows)} rows for {n} poses")
            for r, P in zip(rows, np.asarray(poses, np.float64)):
                self.node[r] = node
                self.rel[16 * r:16 * r + 16] = array("d", np.ascontiguousarray(P).tobytes())
            return
        self.node[row0:row0 + n] = array("q", [node]) * n
        self.rel[16 * row0:16 * (row0 + n)] = array("d", np.ascontiguousarray(poses, np.float64).tobytes())

    def set_node_poses(self, rows: np.ndarray, poses: np.ndarray) -> None:
        """Replace the node-from-frame poses of settled ``rows`` (any order) by ``poses`` (n, 4, 4)."""
        for r, P in zip(np.asarray(rows).tolist(), np.asarray(poses, np.float64)):
            self.rel[16 * r:16 * r + 16] = array("d", np.ascontiguousarray(P).tobytes())

    def fragments(self) -> np.ndarray:
        """Fragment id per row (-1: not placed), int64, a copy (a view would pin the array)."""
        return np.frombuffer(self.fragment, dtype=np.int64).copy() if len(self) else np.zeros(0, np.int64)

    def node_pose(self, row: int) -> np.ndarray:
        """Node-from-frame pose of a settled row."""
        return np.array(self.rel[16 * row:16 * row + 16], dtype=np.float64).reshape(4, 4)

    def __len__(self) -> int:
        return len(self.index)


class SlamMap(Protocol):
    """The read side of a back-end's map (``backend.map``): what the run loop, fusion and the
    output writers read. Poses camera-to-world, metres; frames addressed by log row."""

    log: FrameLog

    def pose_of_log(self, row: int) -> np.ndarray | None:
        """Camera-to-world pose of log row ``row`` now (None when unregistered)."""

    def current_pose(self) -> np.ndarray | None:
        """Camera-to-world pose of the last placed frame (None when unregistered or none)."""

    def current_placement(self) -> tuple[int, np.ndarray] | None:
        """The last placed frame's component (an id that stays the same across merges into it)
        and the frame's camera-to-world pose in that component's frame, whether or not it is
        the main map (None before the first placed frame)."""

    def in_main(self, fid: int) -> bool:
        """Fragment ``fid`` is registered (in the main map)."""

    def main_fragments(self) -> set[int]:
        """The registered fragments."""

    def components(self) -> list[MapComponent]:
        """After the back-end's ``finish``: every connected component with its frames, the main
        map first, then by frames (:mod:`c3f_slam.pipeline.components`)."""

    def trajectory(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(frame indices, timestamps, poses (N, 4, 4) NaN when unregistered, registered mask)."""

    def keyframe_graph(self) -> KeyframeGraph | None:
        """The global keyframe graph for keyframe_graph.json (None: the back-end has none)."""

    def n_keyframes(self) -> int:
        """Keyframes so far (progress display)."""


class SlamBackend(Protocol):
    """A back-end the run loop drives (:mod:`c3f_slam.pipeline.run`): a tracker that holds its
    map (``map``, :class:`SlamMap`).

    Constructed as ``factory(cfg, K, metric, timings, keyframe_cache=folder or None)``
    (:data:`BackendFactory`); ``K`` the 3x3 intrinsics, ``metric`` the descriptors' distance
    (``l2``), ``keyframe_cache`` a folder it may use for stored features.
    """

    mode: str  #: "full" or "odometry" (SlamConfig.mode)
    map: SlamMap

    def skip(self, index: int, stamp: float) -> None:
        """A streamed frame that was not processed (black / saturated / featureless)."""

    def add(self, frame: FrameInput) -> FrameDecision:
        """Process one frame; what was done with it (its fragment id for fusion, -1 = not placed)."""

    def finish(self) -> None:
        """End of the stream: close what is open, final optimisation."""

    def close(self) -> None:
        """Free files and folders (always called, also after errors); the map stays readable."""

    def stats(self) -> dict:
        """Counters for summary.json."""


class BackendFactory(Protocol):
    def __call__(self, cfg: SlamConfig, K: np.ndarray, metric: str = "l2", timings: Timings | None = None,
                 keyframe_cache: str | Path | None = None) -> SlamBackend: ...
