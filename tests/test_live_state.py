"""The live page's store (c3f_slam/live/state.py): versions and ``since``, the run-length timeline,
wall rows and resets, delays, bounded memory over a long run, the page's JPEG, thread safety."""

from __future__ import annotations

import ast
import base64
import json
import threading
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from c3f_slam.frames.quality import QUALITY_CAUSES
from c3f_slam.live.state import DECISION_KINDS, DELAY_SAMPLES, SKIP_KINDS, LiveState, WallRow

ROOT = Path(__file__).resolve().parents[1]
A = 12


def make_state(mask: np.ndarray | None = None) -> LiveState:
    K = [[100.0, 0.0, 80.0], [0.0, 100.0, 60.0], [0.0, 0.0, 1.0]]
    return LiveState(source={"name": "clip.mp4", "kind": "video", "rate_fps": 30.0},
                     camera={"K": K, "width": 160, "height": 120}, tissue_mask=mask,
                     wall={"cell_length_m": 0.005, "angle_bins": A, "segment_m": 0.05, "threshold": 0.2})


def pose_at(z: float) -> np.ndarray:
    T = np.eye(4)
    T[2, 3] = z
    return T


def row(i: int, radius: float = 0.02, unseen: tuple[int, ...] = ()) -> WallRow:
    observed = np.ones(A, bool)
    observed[list(unseen)] = False
    r = np.full(A, radius)
    r[0] = np.nan
    return WallRow(i=i, centre=(0, 0, (i + 0.5) * 0.005), N=(1, 0, 0), B=(0, 1, 0), radius=r, observed=observed,
                   measured=observed.copy(), colour=np.full((A, 3), (200, 120, 110), np.uint8))


def publish(state: LiveState, index: int, decision: str = "extended", rgb: np.ndarray | None = None,
            z: float | None = None, captured_at: float | None = None) -> None:
    captured_at = time.time() if captured_at is None else captured_at
    state.publish_frame(index=index, timestamp=index / 30, captured_at=captured_at, decision=decision, rgb=rgb,
                        pose=None if z is None else pose_at(z))


def grey(value: int = 128) -> np.ndarray:
    return np.full((120, 160, 3), value, np.uint8)


def test_versions_and_since_return_only_changes():
    state = make_state()
    assert state.version == 0
    first = state.snapshot(0)
    assert first["version"] == 0 and first["frame"] is None and first["status"] == "running"
    publish(state, 0, "lone", grey(), z=0.0)
    publish(state, 1, "extended", grey(), z=0.002)
    state.update_wall([row(0), row(1)])
    state.add_map_points(np.zeros((5, 3)), np.zeros((5, 3), np.uint8))
    v = state.version
    assert v == 4  # one bump per mutation
    publish(state, 2, "extended", grey(), z=0.004)
    state.update_wall([row(2)])
    state.add_map_points(np.ones((3, 3)), np.zeros((3, 3), np.uint8))
    snap = state.snapshot(v)
    assert snap["version"] == v + 3 and not snap["full"]
    assert [r["i"] for r in snap["wall"]["rows"]] == [2]
    assert snap["path"] == {"start": 2, "points": [[0.0, 0.0, 0.004]]}
    assert snap["map"]["start"] == 5 and snap["map"]["count"] == 8
    assert np.frombuffer(base64.b64decode(snap["map"]["xyz"]), "<f4").reshape(-1, 3).tolist() == [[1, 1, 1]] * 3
    assert snap["timeline"] == {"start": 1, "entries": [[1, 2, "extended"]]}  # the entry that changed
    assert snap["frame"]["index"] == 2 and snap["frame"]["version"] == v + 1
    assert snap["pose"][11] == pytest.approx(0.004) and snap["pose_index"] == 2
    nothing = state.snapshot(state.version)  # a page that is up to date gets no rows, points or entries
    assert nothing["wall"]["rows"] == [] and nothing["path"]["points"] == [] and nothing["map"]["xyz"] == ""
    assert nothing["timeline"]["entries"] == [] and nothing["timeline"]["start"] == 2
    late = state.snapshot(0)  # a page that comes late gets everything
    assert late["full"] and [r["i"] for r in late["wall"]["rows"]] == [0, 1, 2]
    assert late["map"]["start"] == 0 and len(base64.b64decode(late["map"]["rgb"])) == 8 * 3
    assert len(late["path"]["points"]) == 3
    assert late["timeline"]["entries"] == [[0, 0, "lone"], [1, 2, "extended"]]
    assert state.snapshot(10**6)["full"]  # a version this state never had: everything
    json.dumps(late, allow_nan=False)


def test_timeline_merges_runs_and_drops():
    state = make_state()
    for i, kind in enumerate(["lone", "extended", "extended", "keyframe", "extended", "blurred", "duplicate"]):
        publish(state, i, kind)
    state.drop_frames(7, 9)
    state.drop_frames(10, 10)
    publish(state, 11, "extended")
    publish(state, 12, "rejoined")
    assert state.snapshot()["timeline"]["entries"] == [
        [0, 0, "lone"], [1, 2, "extended"], [3, 3, "keyframe"], [4, 4, "extended"], [5, 5, "blurred"],
        [6, 6, "duplicate"], [7, 10, "dropped"], [11, 11, "extended"], [12, 12, "rejoined"]]
    assert state.snapshot()["latest_index"] == 12
    with pytest.raises(ValueError, match="last index"):
        state.drop_frames(5, 4)


def test_unknown_kind_is_refused():
    state = make_state()
    with pytest.raises(ValueError, match="unknown frame kind 'tracked'"):
        publish(state, 0, "tracked")
    for kind in (*DECISION_KINDS, "rejoined", *SKIP_KINDS):
        publish(state, 0, kind)
    with pytest.raises(ValueError, match="unknown final status"):
        state.finish("done")


def _module_tuple(path: Path, name: str, known: dict[str, tuple]) -> tuple[str, ...]:
    """The tuple of strings assigned to ``name`` in ``path`` (names and starred names resolved)."""
    tree = ast.parse(path.read_text())
    constants: dict[str, str] = {}
    for node in tree.body:
        if isinstance(node, ast.Assign):
            targets = node.targets[0].elts if isinstance(node.targets[0], ast.Tuple) else node.targets
            values = node.value.elts if isinstance(node.value, ast.Tuple) else [node.value]
            for target, value in zip(targets, values):
                if isinstance(value, ast.Constant) and isinstance(value.value, str):
                    constants[target.id] = value.value
            if isinstance(node.targets[0], ast.Name) and node.targets[0].id == name:
                out: list[str] = []
                for elt in node.value.elts:
                    if isinstance(elt, ast.Starred):
                        out.extend(known[elt.value.id])
                    else:
                        out.append(elt.value if isinstance(elt, ast.Constant) else constants[elt.id])
                return tuple(out)
    raise AssertionError(f"{name} not found in {path}")


def test_kinds_are_the_pipelines():
    """The timeline's kinds are the back-end's decisions and the run's skip reasons (read from their
    sources: importing c3f_slam.pipeline loads Open3D, seconds for a tuple)."""
    assert DECISION_KINDS == _module_tuple(ROOT / "c3f_slam/pipeline/frame_step.py", "KINDS", {})
    assert SKIP_KINDS == _module_tuple(ROOT / "c3f_slam/pipeline/run.py", "SKIP_REASONS",
                                       {"QUALITY_CAUSES": QUALITY_CAUSES})


def test_wall_rows_are_replaced_and_reset():
    state = make_state()
    state.update_wall([row(0), row(1), row(2)])
    page = state.snapshot(0)
    r0 = page["wall"]["rows"][0]
    assert r0["radius"][0] is None and r0["radius"][1] == 0.02 and r0["observed"] == "1" * A
    assert base64.b64decode(r0["colour"])[:3] == bytes((200, 120, 110))
    assert page["wall"]["epoch"] == 0 and not page["wall"]["reset"] and page["wall"]["reason"] is None
    v = page["version"]
    state.update_wall([row(1, radius=0.03, unseen=(3, 4))])
    snap = state.snapshot(v)
    assert [r["i"] for r in snap["wall"]["rows"]] == [1]
    assert snap["wall"]["rows"][0]["radius"][1] == 0.03 and snap["wall"]["rows"][0]["observed"][3:5] == "00"
    assert [r["i"] for r in state.snapshot(0)["wall"]["rows"]] == [0, 2, 1]  # ordered by version
    with pytest.raises(ValueError, match="cells, the grid 12"):
        state.update_wall([WallRow(i=0, centre=(0, 0, 0), N=(1, 0, 0), B=(0, 1, 0), radius=np.ones(5),
                                   observed=np.ones(5, bool), measured=np.ones(5, bool),
                                   colour=np.zeros((5, 3), np.uint8))])

    publish(state, 0, "extended", z=0.0)
    state.add_map_points(np.zeros((4, 3)), np.zeros((4, 3), np.uint8))
    v = state.snapshot(0)["version"]  # a page polled before the reset
    state.reset_wall("tracking lost at frame 40")
    state.update_wall([row(7)])
    state.add_map_points(np.ones((2, 3)), np.zeros((2, 3), np.uint8))
    snap = state.snapshot(v)
    assert snap["wall"]["reset"] and snap["wall"]["epoch"] == 1
    assert snap["wall"]["reason"] == "tracking lost at frame 40"
    assert [r["i"] for r in snap["wall"]["rows"]] == [7]
    assert snap["map"]["start"] == 0 and snap["map"]["count"] == 2  # cut to 0, then append
    assert snap["path"] == {"start": 0, "points": []} and snap["pose"] is None and snap["segments"] == []
    after = state.snapshot(snap["version"])
    assert not after["wall"]["reset"] and after["wall"]["epoch"] == 1


def test_delays_median_and_p95():
    state = make_state()
    empty = state.snapshot()["rates"]["delays"]
    assert empty["capture_to_publish_ms"] == {"median": None, "p95": None, "samples": 0}
    for i in range(10):
        publish(state, i, captured_at=time.time() - 0.1)
    publish(state, 10, captured_at=time.time() + 60)  # a clock that went back: ignored
    shown = [10.0, 20.0, 30.0, 40.0, 1000.0]
    for i, d in enumerate(shown):
        state.report_shown(i, d)
    state.report_shown(5, -3.0)
    state.report_shown(6, 7200e3)
    state.set_rates(source_fps=30.0, processed_fps=12.5, dropped=30, taken=90)
    rates = state.snapshot()["rates"]
    pub, disp = rates["delays"]["capture_to_publish_ms"], rates["delays"]["capture_to_display_ms"]
    assert pub["samples"] == 10 and 100 <= pub["median"] < 150 and pub["p95"] >= pub["median"]
    assert disp == {"median": 30.0, "p95": pytest.approx(float(np.percentile(shown, 95)), abs=0.1), "samples": 5}
    assert rates["dropped_share"] == 0.25 and rates["source_fps"] == 30.0 and rates["processed_fps"] == 12.5


def test_memory_stays_bounded_over_a_long_run():
    state = make_state()
    rgb = grey()
    n = 20_000
    for i in range(n):
        publish(state, i, "keyframe" if i % 1000 == 0 else "extended", rgb=rgb, z=i * 1e-4)
        if i % 100 == 0:
            state.report_shown(i, 50.0)
    sizes = state.sizes()
    assert sizes["publish_delays"] == DELAY_SAMPLES and sizes["images"] == 1
    assert sizes["timeline"] == 40  # a keyframe and a run of extended frames per 1,000
    assert sizes["path"] <= n * 1e-4 / 1e-3 + 1  # a point per mm of motion
    assert state.snapshot(state.version - 1)["timeline"]["entries"] == [[19001, 19999, "extended"]]


def test_frame_jpeg_shows_the_mask():
    yy, xx = np.mgrid[:60, :80]
    mask = (yy - 30) ** 2 + (xx - 40) ** 2 < 25**2  # half the frame's size: resized to it
    state = make_state(mask)
    assert state.frame_jpeg() is None
    publish(state, 0, rgb=grey(128))
    version, data = state.frame_jpeg()
    img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_GRAYSCALE)
    assert img.shape == (120, 160)
    assert img[:10, :10].mean() < 0.5 * img[50:70, 70:90].mean()  # a corner outside, the centre inside
    assert state.frame_jpeg() == (version, data) and state.current_jpeg() is state.current_jpeg()  # cached
    publish(state, 1, rgb=None)  # unreadable: the image stays
    assert state.frame_jpeg()[0] == version and state.snapshot()["frame"]["index"] == 0
    publish(state, 2, "lost", rgb=grey(90))
    jpeg = state.current_jpeg()
    assert jpeg.version > version and jpeg.index == 2 and jpeg.decision == "lost"
    with pytest.raises(ValueError, match="uint8"):
        publish(state, 3, rgb=np.zeros((4, 4, 3)))


def test_snapshot_is_json_able():
    state = make_state()
    state.set_segments([{"index": np.int64(0), "start_m": 0.0, "end_m": 0.05, "unseen_share": np.float32(0.3),
                         "state": "current"}])
    state.add_alert({"segment": 0, "start_m": 0.0, "end_m": 0.05, "unseen_share": 0.3,
                     "gap": {"clock": 2, "s_from_m": 0.01, "s_to_m": 0.02, "area_cm2": float("nan")},
                     "frame": 12, "time": 0.4})
    state.finish("finished", summary={"out": Path("/tmp/run"), "unseen_share": np.float64(0.23), "bad": np.inf})
    snap = state.snapshot()
    text = json.dumps(snap, allow_nan=False, separators=(",", ":"))
    assert snap["summary"] == {"out": "/tmp/run", "unseen_share": 0.23, "bad": None}
    assert snap["alerts"][0]["gap"]["area_cm2"] is None and snap["alerts"][0]["version"] == 2
    assert snap["status"] == "finished" and '"unseen_share":0.23' in text
    with pytest.raises(ValueError, match="segment without state"):
        state.set_segments([{"index": 0, "start_m": 0.0, "end_m": 0.05, "unseen_share": 0.3}])


def test_one_producer_and_several_readers():
    state = make_state(np.ones((120, 160), bool))
    stop = threading.Event()
    failures: list[BaseException] = []

    def produce() -> None:
        try:
            i = 0
            while not stop.is_set():
                publish(state, i, "extended", rgb=grey(i % 256), z=i * 1e-3)
                if i % 5 == 0:
                    state.update_wall([row(i % 40)])
                    state.add_map_points(np.random.rand(20, 3), np.zeros((20, 3), np.uint8))
                if i % 50 == 49:
                    state.reset_wall("test")
                i += 1
        except BaseException as exc:
            failures.append(exc)

    def read() -> None:
        try:
            since, last = 0, 0
            while not stop.is_set():
                snap = state.snapshot(since)
                json.dumps(snap, allow_nan=False)
                assert snap["version"] >= last
                last = since = snap["version"]
                jpeg = state.frame_jpeg()
                assert jpeg is None or jpeg[0] <= state.version
        except BaseException as exc:
            failures.append(exc)

    threads = [threading.Thread(target=produce)] + [threading.Thread(target=read) for _ in range(3)]
    for t in threads:
        t.start()
    time.sleep(1.0)
    stop.set()
    for t in threads:
        t.join(timeout=10)
    assert not failures, failures[0]
    assert state.version > 10
