"""The back-end's parts the run loop sees: per-stage timings and the decision record of a frame."""

from __future__ import annotations

import time

import pytest

from c3f_slam.pipeline.frame_step import KINDS, DecisionCounts, FrameDecision
from c3f_slam.pipeline.timings import Timings


def test_timings_add_each_block_and_each_step_to_its_stage():
    t = Timings()
    with t.stage("matching"):
        time.sleep(0.01)
    with pytest.raises(ValueError), t.stage("matching"):  # a block that raises is counted too
        raise ValueError
    items = list(t.timed("io", iter([1, 2, 3])))
    assert items == [1, 2, 3]
    assert 0.01 <= t.seconds["matching"] < 1.0 and 0.0 < t.seconds["io"] < 0.5
    d = t.as_dict(10)
    assert set(d) == {*Timings.STAGES, "total"} and d["depth"] == {"seconds": 0.0, "ms_per_frame": 0.0}
    assert d["matching"]["ms_per_frame"] == pytest.approx(100 * t.seconds["matching"])
    assert d["total"]["frames_per_second"] == pytest.approx(10 / (t.seconds["matching"] + t.seconds["io"]))


def test_frame_decisions_are_counted_by_kind():
    counts = DecisionCounts()
    decisions = [FrameDecision(0, 0, "lone", "first"), FrameDecision(1, 0, "extended"),
                 FrameDecision(2, 1, "keyframe", "size", rejoined=True), FrameDecision(3, 2, "attached", "overlap"),
                 FrameDecision(4, -1, "lost")]
    for d in decisions:
        counts.add(d)
    assert [d.opened for d in decisions] == [True, False, True, True, False]
    assert counts.as_dict() == {**dict.fromkeys(KINDS, 1), "rejoined": 1}
    with pytest.raises(ValueError, match="unknown decision kind 'moved'"):
        FrameDecision(5, 3, "moved")
