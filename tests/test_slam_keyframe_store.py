"""Keyframe features on disk (:mod:`c3f_slam.pipeline.keyframe_store`): exact round trips,
the LRU, identical SLAM results with the features in RAM or on disk, the run's cache folder
removed at the end (also on errors), one-line errors naming the folder."""

from __future__ import annotations

import errno
import json
import os
from pathlib import Path

import numpy as np
import pytest

from c3f_core.errors import InputError
from c3f_slam.config import preset as slam_preset
from c3f_slam.pipeline import SlamConfig, run_slam
from c3f_slam.pipeline.frame_step import FrameInput
from c3f_slam.pipeline.frontend import FrameFeatures
from c3f_slam.pipeline.keyframe_store import CACHE_DIR, DATA_FILE, KeyframeStore
from c3f_slam.pipeline.slam import FragmentSlam
from datamodules.synthetic.fixture import make_tiny_sequence
from tests.fake_places import PlaceWorld


def _features(rng: np.random.Generator, index: int, dtype: type, n: int, width: int = 128) -> FrameFeatures:
    """Random features: descriptors (n, width) of ``dtype``, points (n, 3) float32 metres with
    some NaN (no depth), pixel keypoints that the store drops."""
    if dtype == np.uint8:
        desc = rng.integers(0, 256, (n, width), dtype=np.uint8)
    else:
        desc = rng.standard_normal((n, width)).astype(dtype)
    pts = rng.uniform(-0.02, 0.02, (n, 3)).astype(np.float32)
    pts[rng.random(n) < 0.2, 2] = np.nan
    xy = rng.uniform(0, 64, (n, 2)).astype(np.float32)
    return FrameFeatures(index, index / 30.0, xy, desc, pts)


def _same(a: FrameFeatures, b: FrameFeatures) -> bool:
    """Bit-for-bit equal stored features (NaN included)."""
    return (a.index == b.index and a.timestamp == b.timestamp and a.xy.shape == b.xy.shape == (0, 2)
            and a.descriptors.dtype == b.descriptors.dtype and a.points.dtype == b.points.dtype
            and a.descriptors.tobytes() == b.descriptors.tobytes() and a.points.tobytes() == b.points.tobytes())


@pytest.mark.parametrize("dtype", [np.uint8, np.float16])
def test_round_trip_exact_with_nan_points(tmp_path, dtype):
    rng = np.random.default_rng(0)
    feats = [_features(rng, 10 + i, dtype, n) for i, n in enumerate([36, 0, 5, 80, 1])]
    ram, disk = KeyframeStore(), KeyframeStore(tmp_path / "c", lru=2)
    for f in feats:
        ram.append(f)
        disk.append(f)
    assert len(ram) == len(disk) == len(feats)
    assert disk.disk_bytes == sum(f.descriptors.nbytes + f.points.nbytes for f in feats)
    assert (tmp_path / "c" / DATA_FILE).stat().st_size == disk.disk_bytes
    assert ram.disk_bytes == 0 and ram.nbytes == sum(f.descriptors.nbytes + f.points.nbytes for f in feats)
    for k in [0, 3, 1, 4, 2, -1, -5]:  # most of them not in the LRU of 2
        assert _same(ram[k], disk[k]), k
        assert np.isnan(disk[k].points).any() == np.isnan(feats[k].points).any()
    np.testing.assert_array_equal(disk.timestamps, [f.timestamp for f in feats])
    np.testing.assert_array_equal(ram.timestamps, disk.timestamps)
    with pytest.raises(IndexError):
        disk[len(feats)]
    disk.close()
    assert not (tmp_path / "c").exists()
    assert disk.disk_bytes > 0 and len(disk.timestamps) == len(feats)  # records survive close


def test_lru_returns_equal_arrays_and_reads_the_file_once(tmp_path, monkeypatch):
    rng = np.random.default_rng(1)
    store = KeyframeStore(tmp_path / "c", lru=3)
    feats = [_features(rng, i, np.uint8, 20) for i in range(6)]
    for f in feats:
        store.append(f)
    reads = []
    real = os.preadv
    monkeypatch.setattr(os, "preadv", lambda *a: reads.append(a[2]) or real(*a))
    for k in (5, 4, 3):  # the last appended: in the LRU, no read
        np.testing.assert_array_equal(store[k].descriptors, feats[k].descriptors)
    assert reads == []
    first = store[0]  # read, then cached
    again = store[0]
    assert len(reads) == 1 and again is first and _same(first, KeyframeStore._read(store, 0))
    assert not first.descriptors.flags.writeable  # cached arrays are protected
    np.testing.assert_array_equal(first.descriptors, feats[0].descriptors)
    np.testing.assert_array_equal(first.points, feats[0].points)
    # RAM held: 34-byte records at capacity and the LRU's arrays (3 keyframes), not all six
    assert store.nbytes < store._meta.nbytes + 4 * 20 * (128 + 12)
    store.close()


def _revisiting_walk(n: int = 90, places: int = 30) -> list[int]:
    """Places visited forth and back (ping-pong) so that old keyframes are candidates again."""
    cycle = list(range(places)) + list(range(places - 2, 0, -1))
    return [cycle[k % len(cycle)] for k in range(n)]


def _fake_run(world: PlaceWorld, folder: Path | None) -> tuple[FragmentSlam, list[bytes]]:
    """One keyframe per frame on ``world``; the matcher checks what it gets from the store and
    records the bytes of every stored keyframe it is given."""
    cfg = slam_preset("colon", fragments={"min_correspondences": 10**6}, fusion={"enabled": False},
                                   candidates={"max_candidates": 6}, optimization={"small_map": 10})
    slam = FragmentSlam(cfg.for_frame_size(128, 128), np.eye(3), keyframe_cache=folder)
    if folder is not None:
        slam.map.keyframes = KeyframeStore(folder, lru=4)  # small LRU: most candidates come from the file
    seen: list[bytes] = []

    def match(a: FrameFeatures, b: FrameFeatures):
        assert a.descriptors.tobytes() == world.desc[world.place[a.index]].tobytes()
        seen.append(a.descriptors.tobytes() + a.points.tobytes())
        return world.match(a, b)

    slam.match = match
    for i, p in enumerate(_revisiting_walk()):
        slam.add(FrameInput(world.frame(i, p), np.zeros((4, 4), np.float32)))
    slam.finish()
    return slam, seen


def test_fake_world_identical_in_ram_and_on_disk(tmp_path):
    ram, seen_ram = _fake_run(PlaceWorld(30, reach=2, seed=4, graded=True), None)
    disk, seen_disk = _fake_run(PlaceWorld(30, reach=2, seed=4, graded=True), tmp_path / "kf")
    assert disk.map.keyframes.on_disk and not ram.map.keyframes.on_disk
    assert seen_ram == seen_disk and len(seen_ram) > 100
    assert [(e.i, e.j, e.kind, e.uncertain) for e in ram.map.graph.edges] == \
        [(e.i, e.j, e.kind, e.uncertain) for e in disk.map.graph.edges]
    assert ram.map.graph.pose_array().tobytes() == disk.map.graph.pose_array().tobytes()
    idx_r, st_r, P_r, reg_r = ram.map.trajectory()
    idx_d, st_d, P_d, reg_d = disk.map.trajectory()
    assert P_r.tobytes() == P_d.tobytes() and (reg_r == reg_d).all() and (st_r == st_d).all()
    s_r, s_d = ram.stats(), disk.stats()
    assert s_r["keyframe_disk_bytes"] == 0 and s_d["keyframe_disk_bytes"] == 90 * 40 * (128 + 12)
    assert s_d["keyframe_memory_bytes"] < s_r["keyframe_memory_bytes"]
    for key in ("global_edges", "loop_edges", "global_optimizations", "keyframe_matches_by_source"):
        assert s_r[key] == s_d[key], key
    disk.close()
    assert not (tmp_path / "kf").exists()


# ---------------------------------------------------------------------- run_slam


@pytest.fixture(scope="module")
def seq(tmp_path_factory) -> Path:
    return make_tiny_sequence(tmp_path_factory.mktemp("kfstore") / "seq", frames=30, size=128, seed=3)


@pytest.mark.e2e
def test_run_slam_identical_and_cache_removed(seq, tmp_path):
    """The run's trajectory and keyframe graph are the same with the keyframe cache on
    (default) and off; the cache folder existed during the run and is gone after it."""
    seen = {}

    class Spy(FragmentSlam):
        def add(self, frame):
            seen["on_disk"] = self.map.keyframes.on_disk
            seen["file"] = seen.get("file") or (self.map.keyframes.folder is not None
                                                and (self.map.keyframes.folder / DATA_FILE).is_file())
            return super().add(frame)

    outs = {}
    for cache in (True, False):
        cfg = slam_preset("colon", fragments={"min_correspondences": 15}, fusion={"enabled": False},
                                       keyframes={"cache": cache})
        out = tmp_path / f"cache_{cache}"
        s = run_slam(seq, out, cfg, progress=False, slam_factory=Spy)
        assert seen["on_disk"] is cache and seen["file"] is cache
        assert not (out / CACHE_DIR).exists()
        assert s["keyframes"] >= 2 and (s["keyframe_disk_bytes"] > 0) is cache
        outs[cache] = (out, s)
        seen.clear()
    (a, sa), (b, sb) = outs[True], outs[False]
    assert (a / "trajectory.txt").read_bytes() == (b / "trajectory.txt").read_bytes()
    assert json.loads((a / "keyframe_graph.json").read_text()) == json.loads((b / "keyframe_graph.json").read_text())
    assert sa["keyframe_memory_bytes"] < sb["keyframe_memory_bytes"]


def test_run_slam_removes_cache_on_error(seq, tmp_path):
    out = tmp_path / "boom"

    class Boom(FragmentSlam):
        def add(self, frame):
            store = self.map.keyframes
            if len(store) >= 2:  # the cache is in the run being built (beside OUT)
                assert store.folder.name == CACHE_DIR and store.folder.parent.parent == tmp_path
                assert (store.folder / DATA_FILE).stat().st_size > 0
                raise RuntimeError("planted failure")
            return super().add(frame)

    cfg = slam_preset("colon", fragments={"min_correspondences": 15}, fusion={"enabled": False})
    with pytest.raises(RuntimeError, match="planted failure"):
        run_slam(seq, out, cfg, progress=False, slam_factory=Boom)
    assert not (out / CACHE_DIR).exists()
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "error" and summary["keyframes"] >= 2


# ---------------------------------------------------------------------- errors


def test_unwritable_folder_is_one_input_error_line(tmp_path):
    blocker = tmp_path / "not_a_folder"
    blocker.write_text("x")
    bad = blocker / CACHE_DIR  # a folder cannot be made under a file (also as root)
    with pytest.raises(InputError) as err:
        FragmentSlam(SlamConfig().for_frame_size(128, 128), np.eye(3), keyframe_cache=bad)
    msg = str(err.value)
    assert str(bad) in msg and "\n" not in msg


def test_disk_full_is_one_input_error_line(tmp_path, monkeypatch):
    store = KeyframeStore(tmp_path / "c")

    def full(*_a):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(os, "pwrite", full)
    with pytest.raises(InputError) as err:
        store.append(_features(np.random.default_rng(2), 0, np.uint8, 10))
    msg = str(err.value)
    assert str(tmp_path / "c") in msg and "No space left" in msg and "\n" not in msg
    assert len(store) == 0
    store.close()
