"""The alert of the live view: the scope leaves a segment with more unseen wall than a threshold.

A segment is ``coverage.segment`` metres of centreline (:mod:`c3f_slam.coverage.incremental`).
The scope is *in* the segment that holds its arc length; it has *left* segment k once it is
more than ``margin`` metres outside it (either way: inserting or withdrawing). A segment that
was left is judged once its rows reach its end (they lag the camera); if its unseen share is
above ``threshold`` an :class:`Alert` is raised, once per visit (entering the segment again
re-arms it). The alert says where the gap is: the largest connected region of unseen cells, its
arc lengths and area, and its direction as a clock hour seen from the scope at that moment
(12 = image up).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from c3f_slam.coverage.incremental import IncrementalWall, clock_position


@dataclass(frozen=True)
class Alert:
    """A segment left with ``unseen_share`` (0..1) above the threshold. Metres; ``gap_area`` m^2;
    ``clock`` 1..12 (None without a gap region); ``frame`` the stream index when raised."""

    segment: int
    start_m: float
    end_m: float
    unseen_share: float
    clock: int | None
    gap_from_m: float | None
    gap_to_m: float | None
    gap_area: float | None
    frame: int
    time: float

    def as_dict(self) -> dict:
        return {"segment": self.segment, "start_m": self.start_m, "end_m": self.end_m,
                "unseen_share": self.unseen_share, "frame": self.frame, "time": self.time,
                "gap": None if self.clock is None else {
                    "clock": self.clock, "s_from_m": self.gap_from_m, "s_to_m": self.gap_to_m,
                    "area_cm2": (self.gap_area or 0.0) * 1e4}}

    def message(self) -> str:
        """One line for a person: segment, share, where the gap is (cm)."""
        text = (f"segment {self.segment + 1} ({100 * self.start_m:.0f}-{100 * self.end_m:.0f} cm): "
                f"{100 * self.unseen_share:.0f} % of the wall unseen")
        if self.clock is not None:
            text += (f", gap at {self.clock} o'clock, {100 * self.gap_from_m:.0f}-{100 * self.gap_to_m:.0f} cm "
                     f"({1e4 * self.gap_area:.1f} cm2)")
        return text


class SegmentWatch:
    """Follows the scope from segment to segment and raises the alerts (:meth:`update` per frame)."""

    def __init__(self, segment: float, threshold: float, margin: float) -> None:
        if not 0 <= threshold <= 1:
            raise ValueError(f"live alert threshold must be a share in 0..1, got {threshold}")
        if margin < 0:
            raise ValueError(f"live alert margin must be >= 0 metres, got {margin}")
        self.segment, self.threshold, self.margin = segment, threshold, margin
        self.current: int | None = None  #: the segment the scope is in
        self.left: set[int] = set()  #: segments left and not judged yet (their rows lag)
        self.alerts: list[Alert] = []

    def reset(self) -> None:
        """The map restarted: nothing is followed (alerts raised stay)."""
        self.current, self.left = None, set()

    def update(self, s: float | None, wall: IncrementalWall, T_wc: np.ndarray, frame: int,
               now: float) -> list[Alert]:
        """The scope at arc length ``s`` (metres; None: unknown) with pose ``T_wc``; returns new alerts."""
        if s is not None:
            k = max(0, int(s // self.segment))
            if self.current is None:
                self.current = k
            elif k != self.current and self._outside(s, self.current):
                self.left.add(self.current)
                self.current = k
            self.left.discard(self.current)  # back in a segment before it was judged: not left
        new = []
        for j in sorted(self.left):
            if wall.line.rows_end < (j + 1) * self.segment - 1e-9 and not wall.line.finished:
                continue  # its rows do not reach its end yet
            self.left.discard(j)
            share = wall.segment_share(j)
            if share is None or share <= self.threshold:
                continue
            gap = wall.largest_gap(j)
            end = min((j + 1) * self.segment, wall.line.rows_end)
            alert = Alert(segment=j, start_m=j * self.segment, end_m=end, unseen_share=share,
                          clock=clock_position(gap.direction, T_wc) if gap else None,
                          gap_from_m=gap.s_from if gap else None, gap_to_m=gap.s_to if gap else None,
                          gap_area=gap.area if gap else None, frame=frame, time=now)
            self.alerts.append(alert)
            new.append(alert)
        return new

    def _outside(self, s: float, k: int) -> bool:
        return s < k * self.segment - self.margin or s >= (k + 1) * self.segment + self.margin
