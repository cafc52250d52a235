"""Perception ahead of the back-end (c3f_slam.pipeline.perception): the worker keeps the
order, stays within its bound, really runs beside the loop, hands its errors over at the
frame where they happened, stops when the loop stops; and a run gives the same outputs bit
for bit with and without it (RGB-D mode, and model depth + ContraFeat)."""

from __future__ import annotations

import json
import threading
from pathlib import Path

import numpy as np
import pytest

from c3f_core.errors import InputError
from c3f_slam.config import preset as slam_preset
from c3f_slam.frames.stream import OK, StreamFrame
from c3f_slam.pipeline import run_slam
from c3f_slam.pipeline.perception import PerceivedFrame, Prefetcher
from c3f_slam.pipeline.sources import RunInputs
from datamodules.synthetic.fixture import make_tiny_sequence
from tests import onnx_fixtures as fx


def _frames(n: int):
    rgb = np.zeros((4, 4, 3), np.uint8)
    for i in range(n):
        yield StreamFrame(index=i, timestamp=float(i), rgb=rgb, depth=None, status=OK, mean_luma=0.0)


class _Recorder:
    """A perception that records which frame it is on and can fail at one frame."""

    def __init__(self, fail_at: int | None = None) -> None:
        self.seen: list[int] = []
        self.fail_at = fail_at

    def __call__(self, frame: StreamFrame, io_seconds: float = 0.0) -> PerceivedFrame:
        if frame.index == self.fail_at:
            raise InputError(f"frame {frame.index}: broken")
        self.seen.append(frame.index)
        return PerceivedFrame(frame, seconds={"io": io_seconds})


@pytest.mark.parametrize("prefetch,workers", [(0, 1), (1, 1), (3, 1), (3, 3)])
def test_order_and_bound(prefetch, workers):
    rec = _Recorder()
    ahead = []
    with Prefetcher(_frames(40), rec, prefetch, workers) as frames:
        for k, item in enumerate(frames):
            assert item.frame.index == k
            ahead.append(len(rec.seen) - 1 - k)  # frames perceived beyond the one consumed
    assert sorted(rec.seen) == list(range(40)) and (workers > 1 or rec.seen == list(range(40)))
    # the queue holds at most `prefetch` frames and the reader works on (or hands out) one more;
    # in the loop (prefetch 0) nothing is perceived ahead (that the workers really run ahead:
    # the next tests)
    assert max(ahead) <= prefetch + 1 and (prefetch > 0 or max(ahead) == 0)


def test_perception_runs_beside_the_loop():
    """Frame 1 is perceived while the loop still holds frame 0: the perception of frame 1
    waits for an event that the loop sets only while on frame 0 (serial would deadlock)."""
    on_frame0, done = threading.Event(), []

    def perceive(frame, io_seconds=0.0):
        if frame.index == 1:
            assert on_frame0.wait(timeout=20), "frame 1 was not perceived while the loop was on frame 0"
        return PerceivedFrame(frame)

    with Prefetcher(_frames(3), perceive, prefetch=1, workers=1) as frames:
        for item in frames:
            if item.frame.index == 0:
                on_frame0.set()
            done.append(item.frame.index)
    assert done == [0, 1, 2]


def test_workers_perceive_frames_at_once():
    """Frames 0 and 1 are perceived at the same time: each waits until the other has started
    (one worker at a time would deadlock)."""
    started = {0: threading.Event(), 1: threading.Event()}

    def perceive(frame, io_seconds=0.0):
        if frame.index in started:
            started[frame.index].set()
            assert started[1 - frame.index].wait(timeout=20), "frames 0 and 1 were not perceived at once"
        return PerceivedFrame(frame)

    with Prefetcher(_frames(6), perceive, prefetch=2, workers=2) as frames:
        assert [item.frame.index for item in frames] == list(range(6))


@pytest.mark.parametrize("prefetch,workers", [(0, 1), (2, 1), (3, 2)])
def test_an_error_arrives_at_its_frame(prefetch, workers):
    consumed = []
    with pytest.raises(InputError, match="frame 5: broken"), \
            Prefetcher(_frames(20), _Recorder(5), prefetch, workers) as fr:
        for item in fr:
            consumed.append(item.frame.index)
    assert consumed == [0, 1, 2, 3, 4]


def test_leaving_the_loop_stops_the_worker():
    rec = _Recorder()
    pre = Prefetcher(_frames(10_000), rec, prefetch=2, workers=1)
    with pre as frames:
        for item in frames:
            if item.frame.index == 3:
                break
    assert pre._thread is None and len(rec.seen) <= 3 + 1 + 2 + 1
    rec = _Recorder()
    pre = Prefetcher(_frames(10_000), rec, prefetch=2, workers=2)
    with pre as frames:
        for item in frames:
            if item.frame.index == 3:
                break
    assert pre._thread is None and pre._pool is None and len(rec.seen) <= 3 + 1 + 2 + 1
    with pytest.raises(ValueError, match="prefetch must be >= 0"):
        Prefetcher(_frames(1), rec, -1, 1)
    with pytest.raises(ValueError, match="workers must be >= 1"):
        Prefetcher(_frames(1), rec, 2, 0)


@pytest.fixture(scope="module")
def seq(tmp_path_factory) -> Path:
    return make_tiny_sequence(tmp_path_factory.mktemp("perc") / "seq", frames=24, size=96, seed=5)


def _run(seq: Path, out: Path, prefetch: int, inputs: RunInputs | None = None, workers: int = 1) -> dict:
    cfg = slam_preset("colon", frames={"prefetch": prefetch, "perception_workers": workers},
                      fragments={"min_correspondences": 15})
    return run_slam(seq, out, cfg, inputs, progress=False)


def _same_run(a: Path, b: Path) -> None:
    assert (a / "trajectory.txt").read_bytes() == (b / "trajectory.txt").read_bytes()
    sa, sb = (json.loads((d / "summary.json").read_text()) for d in (a, b))
    for key in ("registered_frames", "frame_decisions", "mesh_triangles", "fragments", "new_fragment_reasons"):
        assert sa.get(key) == sb.get(key), key


@pytest.mark.e2e
def test_prefetched_run_equals_serial_rgbd(seq, tmp_path):
    serial = _run(seq, tmp_path / "serial", 0)
    ahead = _run(seq, tmp_path / "ahead", 3)
    assert serial["registered_frames"] >= 20
    _same_run(tmp_path / "serial", tmp_path / "ahead")
    t = ahead["timings"]
    assert t["wait"]["seconds"] >= 0 and t["total"]["stages_seconds"] > 0 and serial["timings"]["wait"]["seconds"] == 0


@pytest.mark.e2e
def test_prefetched_run_equals_serial_model_depth_and_contrafeat(seq, tmp_path):
    inputs = RunInputs(depth_model=fx.depth_model(tmp_path / "d.onnx", (96, 96)),
                       feature_model=fx.descriptor_model(tmp_path / "f.onnx", (96, 96)))
    serial = _run(seq, tmp_path / "serial", 0, inputs)
    _run(seq, tmp_path / "ahead", 2, inputs)
    _run(seq, tmp_path / "workers", 3, inputs, workers=3)
    assert serial["depth_source"] == "model" and serial["descriptors"] == "contrafeat"
    assert serial["processed"] >= 20
    _same_run(tmp_path / "serial", tmp_path / "ahead")
    _same_run(tmp_path / "serial", tmp_path / "workers")


def test_model_threads_default_to_the_cores_less_one(seq, tmp_path, monkeypatch):
    from c3f_slam.pipeline import sources

    monkeypatch.setattr(sources.os, "cpu_count", lambda: 2)
    assert sources.default_threads() == 1
    monkeypatch.setattr(sources.os, "cpu_count", lambda: 16)
    assert sources.default_threads() == 15
    inputs = RunInputs(depth_model=fx.depth_model(tmp_path / "d.onnx", (96, 96)))
    camera = sources.FrameStream(seq).camera
    desc, depth = sources.make_providers(inputs, camera)
    assert depth.model.onnx.threads == 15
    given = sources.make_providers(RunInputs(depth_model=inputs.depth_model, threads=3), camera)
    assert given[1].model.onnx.threads == 3
