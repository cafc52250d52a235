"""``rerender.mp4``: each input frame beside the reconstruction rendered from that frame's estimated pose.

The right half is the final model (``unseen.ply``: the fused mesh with the unseen wall painted
blue, else ``mesh.ply``) ray cast on the CPU with the run's intrinsics from the frame's
camera-to-world pose in ``trajectory.txt`` (black where the model has no surface). A frame the
gate skipped as a repeat of the one before shows the render of the last registered pose (the
picture is the same); any other frame without a pose says why instead, from the run's
``frame_log.csv``: skipped (the cause), not in the main map (a frame of another component or a
lost one), or not registered. Frames are
those the run read (its stride and frame limit), undistorted as the run read them; panels are
scaled up to at least :data:`MIN_PANEL` pixels high, the render at that size (the intrinsics
scaled) rather than enlarged. With the run's tissue area (``tissue_mask.png``), the render is
shown inside it only: outside it is black, as the scope's border (the map stands for the tissue
area alone).
"""

from __future__ import annotations

import math
import time
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field

import cv2
import numpy as np

from c3f_slam.frames.quality import DUPLICATE
from c3f_slam.pipeline.frame_step import KINDS
from c3f_slam.view.raycast import MeshScene, render_pinhole, scale_intrinsics
from c3f_slam.view.video import centred_text, label

MIN_PANEL = 256  #: pixels: smaller frames are scaled up by an integer factor
MATCH_DT = 1e-4  #: seconds: a trajectory stamp this close to a frame's is that frame's pose
AMBIENT = 0.6  #: the model's colours are the input's, lit already: mild extra shading only


@dataclass
class RenderClock:
    """Seconds spent rendering and frames rendered (the per-frame cost the docs quote)."""

    seconds: float = 0.0
    frames: int = 0
    extra: dict = field(default_factory=dict)

    @property
    def ms_per_frame(self) -> float | None:
        return 1000 * self.seconds / self.frames if self.frames else None


class PoseLookup:
    """Camera-to-world pose of a frame by timestamp (``None``: not registered)."""

    def __init__(self, stamps: np.ndarray, poses: np.ndarray) -> None:
        order = np.argsort(stamps)
        self.stamps, self.poses = np.asarray(stamps, np.float64)[order], np.asarray(poses)[order]

    def __call__(self, t: float) -> np.ndarray | None:
        i = int(np.searchsorted(self.stamps, t))
        for k in (i - 1, i):
            if 0 <= k < len(self.stamps) and abs(self.stamps[k] - t) <= MATCH_DT:
                return self.poses[k]
        return None


def _why_no_pose(frame, outcome: str | None) -> str:
    """The panel's text for a frame without a pose: the stream's skip status, the gate's skip
    cause, a back-end decision outside the main map, or (no log) not registered."""
    if not frame.usable:
        return f"skipped ({frame.status})"
    if outcome in KINDS:  # the back-end's decision: the frame was processed
        return "not in the main map"
    return f"skipped ({outcome})" if outcome else "not registered"


def panel_factor(height: int) -> int:
    """Integer scale that brings a frame ``height`` pixels high to at least :data:`MIN_PANEL`."""
    return max(1, math.ceil(MIN_PANEL / height))


def rerender_frames(frames, *, K: np.ndarray, width: int, height: int, ms: MeshScene, lookup: PoseLookup,
                    clock: RenderClock, tissue: np.ndarray | None = None,
                    outcomes: Mapping[int, str] | None = None) -> Iterator[np.ndarray]:
    """Side-by-side frames (input | reconstruction) of the stream ``frames``
    (:class:`c3f_slam.frames.stream.StreamFrame`) of a ``width`` x ``height`` camera ``K``; ``clock``
    gathers the render time; ``tissue`` ((height, width) bool, True = tissue): the render is
    black outside it; ``outcomes``: frame index -> its outcome in the run's ``frame_log.csv``."""
    f = panel_factor(height)
    w, h = width * f, height * f
    outside = None
    if tissue is not None and not tissue.all():
        outside = cv2.resize(tissue.astype(np.uint8), (w, h), interpolation=cv2.INTER_NEAREST) == 0
    last = None  # the last pose rendered
    for fr in frames:
        left = (cv2.resize(fr.rgb, (w, h), interpolation=cv2.INTER_LINEAR) if fr.rgb is not None
                else np.zeros((h, w, 3), np.uint8))
        T = lookup(fr.timestamp) if fr.usable else None
        outcome = (outcomes or {}).get(fr.index)
        caption = "reconstruction, estimated pose"
        if T is None and outcome == DUPLICATE and last is not None:
            T, caption = last, "reconstruction (repeated frame)"
        if T is None:
            right = np.full_like(left, 40)
            centred_text(right, _why_no_pose(fr, outcome))
        else:
            last = T
            t0 = time.perf_counter()
            right, _ = render_pinhole(ms, scale_intrinsics(K, f), T, w, h, ambient=AMBIENT)
            if outside is not None:
                right[outside] = 0
            clock.seconds += time.perf_counter() - t0
            clock.frames += 1
        label(left, f"input, frame {fr.index}")
        label(right, caption if T is not None else "")
        yield np.concatenate([left, right], axis=1)
