"""The back-end's parts the run loop sees: per-stage timings."""

from __future__ import annotations

import time

import pytest

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
