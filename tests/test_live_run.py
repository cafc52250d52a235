"""``python -m c3f_slam live``: the run of ``run`` fed as a capture feeds it, followed for the page.

The source is paced and the newest frame wins (frames the run cannot take in time are dropped,
counted, and nothing queues); the run folder is the one ``run`` writes plus live.json; pages
that come, poll and go change nothing in the run; Ctrl-C finishes the folder; bad options and
devices are one line. No test here asserts a duration: pacing is checked one-sided (a frame
is never delivered before its time, which load cannot break), the backlog by counting.
"""

from __future__ import annotations

import json
import socket
import sys
import threading
import time
import urllib.request
from pathlib import Path

import cv2
import numpy as np
import pytest

from c3f_slam.cli.main import main
from c3f_slam.config import SlamConfig
from c3f_slam.frames.stream import FrameStream
from c3f_slam.live.loop import LiveRun, run_live
from c3f_slam.live.settings import LiveSettings
from c3f_slam.live.source import PacedSource
from c3f_slam.pipeline.sources import RunInputs
from datamodules.synthetic.fixture import make_tiny_sequence
from tests.bad_input import error_line, interrupt, left_beside

SIZE = 96  #: frame side (pixels): enough correspondences to register the tiny sequence
RUN_FILES = ("summary.json", "trajectory.txt", "frame_log.csv", "coverage.json", "live.json")


@pytest.fixture(scope="module")
def seq(tmp_path_factory) -> Path:
    return make_tiny_sequence(tmp_path_factory.mktemp("live") / "seq", frames=24, size=SIZE, seed=3)


@pytest.fixture(scope="module")
def video(seq, tmp_path_factory) -> Path:
    """The sequence's frames as a 50 fps video, its camera.json beside it."""
    out = tmp_path_factory.mktemp("video") / "clip.avi"
    writer = cv2.VideoWriter(str(out), cv2.VideoWriter_fourcc(*"MJPG"), 50.0, (SIZE, SIZE))
    for png in sorted((seq / "rgb").glob("*.png")):
        writer.write(cv2.imread(str(png)))
    writer.release()
    (out.parent / "camera.json").write_text((seq / "camera.json").read_text())
    return out


def _take_all(source: PacedSource, wait_s: float = 0.0) -> list:
    frames = []
    for frame in source:
        frames.append((frame.index, source.captured_at(frame.index)))
        time.sleep(wait_s)
    return frames


def test_a_video_is_delivered_at_its_own_rate_never_early(video):
    source = PacedSource(FrameStream(video))
    assert source.source_rate() == pytest.approx(50.0)
    frames = _take_all(source)
    assert [i for i, _ in frames] == list(range(24)) and source.dropped == 0
    t = np.array([c for _, c in frames])
    assert np.all(t - t[0] >= np.arange(24) / 50.0 - 2e-3)  # one-sided: load can only make it later


def test_the_newest_frame_wins_when_the_run_is_slower(seq):
    """A consumer slower than the source: frames are dropped, never queued; every frame is
    either taken or dropped, the taken ones in order, and the last one is taken."""
    source = PacedSource(FrameStream(seq), as_fast_as_possible=True)
    frames = _take_all(source, wait_s=0.02)
    taken = [i for i, _ in frames]
    assert source.delivered == 24 and source.dropped > 0
    assert len(taken) + source.dropped == 24
    assert taken == sorted(taken) and taken[-1] == 23
    dropped = source.take_dropped()
    assert sorted(dropped + taken) == list(range(24)) and source.take_dropped() == []


def test_keep_every_frame_takes_them_all_however_slow(seq):
    source = PacedSource(FrameStream(seq), as_fast_as_possible=True, drop=False)
    assert [i for i, _ in _take_all(source, wait_s=0.01)] == list(range(24)) and source.dropped == 0


class _Counting(LiveRun):
    """Records, at each frame the run takes, the frames delivered but neither taken nor dropped."""

    in_flight: list[int]

    def stepped(self, run, item, outcome, decision):
        super().stepped(run, item, outcome, decision)
        src = self.source
        self.__dict__.setdefault("in_flight", []).append(src.delivered - self.taken - src.dropped)


def test_a_live_run_faster_than_processing_drops_frames_and_stays_bounded(seq, tmp_path):
    cfg = SlamConfig().with_(fragments={"min_correspondences": 15})
    settings = LiveSettings(port=0, as_fast_as_possible=True, linger=0)
    live = _Counting(settings, cfg, echo=lambda line: None)
    out = tmp_path / "out"
    summary, live = run_live(seq, out, cfg, RunInputs(), settings, live=live)
    rec = json.loads((out / "live.json").read_text())
    assert rec["frames_delivered"] == 24 and rec["frames_dropped"] > 0
    assert rec["frames_taken"] + rec["frames_dropped"] == 24 == summary["frames"] + rec["frames_dropped"]
    # nothing queues: at most the slot, the perception queue and the workers hold frames
    fc = cfg.frames
    assert max(live.in_flight) <= 1 + fc.prefetch + fc.perception_workers
    for name in RUN_FILES:
        assert (out / name).is_file(), name
    on_disk = json.loads((out / "summary.json").read_text())
    assert on_disk["live"]["frames_dropped"] == rec["frames_dropped"] == summary["live"]["frames_dropped"]
    assert rec["unseen_share_run"] == summary["unseen_share"]  # None when too few frames were taken
    assert left_beside(out) == []


def _poll(url: str, stop: threading.Event, errors: list) -> None:
    """A page that comes late, polls, loads frames and drops its connections half-way."""
    since = 0
    while not stop.is_set():
        try:
            with urllib.request.urlopen(f"{url}state.json?since={since}", timeout=5) as r:
                since = json.loads(r.read())["version"]
            with socket.create_connection((url.split("//")[1].split(":")[0], int(url.rsplit(":", 1)[1].strip("/")))) \
                    as s:
                s.sendall(b"GET /frame.jpg HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")  # and hang up without reading
        except OSError as exc:
            errors.append(repr(exc))
        time.sleep(0.01)


def test_pages_that_come_late_and_go_change_nothing_in_the_run(seq, tmp_path):
    cfg = SlamConfig().with_(fragments={"min_correspondences": 15})
    settings = LiveSettings(port=0, as_fast_as_possible=True, keep_every_frame=True, linger=0)
    alone, _ = run_live(seq, tmp_path / "alone", cfg, RunInputs(), settings)

    stop, errors, threads = threading.Event(), [], []

    class _Watched(LiveRun):
        def opened(self, run):
            super().opened(run)
            for _ in range(3):
                t = threading.Thread(target=_poll, args=(self.server.url, stop, errors), daemon=True)
                t.start()
                threads.append(t)

    try:
        watched, live = run_live(seq, tmp_path / "watched", cfg, RunInputs(), settings,
                                 live=_Watched(settings, cfg, echo=lambda line: None))
    finally:
        stop.set()
        for t in threads:
            t.join(10)
    assert live.state.snapshot(0)["frame"]["index"] == 23
    for name in (*RUN_FILES, "mesh.ply", "unseen.ply"):
        assert (tmp_path / "watched" / name).is_file(), name
    rec = json.loads((tmp_path / "watched" / "live.json").read_text())
    assert rec["frames_dropped"] == 0 and rec["frames_taken"] == 24 and rec["unseen_wall_update"]
    assert 0 <= rec["unseen_share_live"] <= 1 and rec["unseen_share_run"] == watched["unseen_share"]
    assert (tmp_path / "alone" / "trajectory.txt").read_text() == (tmp_path / "watched" / "trajectory.txt").read_text()
    assert alone["unseen_share"] == watched["unseen_share"]
    assert errors == [] or all("Connection" in e or "timed out" in e for e in errors)


def test_ctrl_c_finishes_the_run_folder(seq, tmp_path):
    """SIGINT while a paced live run works: exit 130, the error line last, OUT holds the run so
    far (status error) with live.json, nothing left beside it."""
    out = tmp_path / "out"
    with socket.socket() as probe:  # a free port, to ask the page how far the run is
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    cmd = [sys.executable, "-m", "c3f_slam", "live", str(seq), "--out", str(out), "--port", str(port), "--rate", "3",
           "--linger", "0", "--set", "fragments.min_correspondences=15"]

    def two_frames_taken() -> bool:  # 24 frames at 3 per second take 8 s (frame_log.csv is written buffered)
        try:
            with urllib.request.urlopen(f"http://127.0.0.1:{port}/state.json", timeout=2) as r:
                frame = json.loads(r.read())["frame"]
        except OSError:
            return False
        return frame is not None and frame["index"] >= 2

    code, err = interrupt(cmd, two_frames_taken, delay_s=1.0)
    assert code == 130, err
    assert error_line(err, only=False) == f"error: interrupted; the run so far is in {out} (summary.json status error)"
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "error" and 0 < summary["frames"] < 24
    assert json.loads((out / "live.json").read_text())["frames_taken"] == summary["frames"]
    assert left_beside(out) == []


@pytest.mark.parametrize("args, expected", [
    (["--rate", "0"], "--rate must be > 0"),
    (["--alert-threshold", "1.5"], "--alert-threshold must be a share"),
    (["--port", "70000"], "--port must be 0..65535"),
    (["--linger", "-1"], "--linger must be >= 0"),
])
def test_bad_live_options_are_one_line(seq, tmp_path, capsys, args, expected):
    assert main(["live", str(seq), "--out", str(tmp_path / "o"), *args]) == 2
    assert expected in error_line(capsys.readouterr().err)
    assert not (tmp_path / "o").exists()


def test_a_port_in_use_is_one_line_before_the_run(seq, tmp_path, capsys):
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen(1)
        port = busy.getsockname()[1]
        assert main(["live", str(seq), "--out", str(tmp_path / "o"), "--port", str(port)]) == 2
    assert f"--port {port}" in error_line(capsys.readouterr().err)
    assert not (tmp_path / "o").exists()


def test_a_capture_device_needs_intrinsics_and_must_open(tmp_path, capsys):
    assert main(["live", "7", "--out", str(tmp_path / "o"), "--port", "0"]) == 2
    assert "capture device 7: a capture device needs intrinsics" in error_line(capsys.readouterr().err, only=False)
    assert main(["live", "7", "--out", str(tmp_path / "o"), "--port", "0", "--fov", "90",
                 "--depth-model", "zoo:c3f-depth-r18w32"]) == 2
    assert "capture device 7: does not open" in error_line(capsys.readouterr().err, only=False)


def test_the_page_follows_the_map_part_of_the_placed_frames(tmp_path):
    """A tracking loss starts a new map part (a component in its own frame): the page's wall
    becomes that part's; a rejoin into the earlier part shows the earlier wall again, replayed."""
    from types import SimpleNamespace

    from c3f_slam.camera.intrinsics import PinholeCamera
    from c3f_slam.frames.stream import StreamFrame
    from c3f_slam.pipeline.frame_step import FrameDecision
    from c3f_slam.pipeline.perception import PerceivedFrame
    from c3f_slam.view.raycast import MeshScene, render_pinhole
    from tests.scenes import tube_mesh, tube_views

    cam = PinholeCamera(fx=32.0, fy=32.0, cx=31.5, cy=31.5, width=64, height=64)
    scene = MeshScene.of(tube_mesh(length=0.3, radius=0.02, margin=0.05, ds=0.001, n_theta=120))
    placement: list = [None]
    backend = SimpleNamespace(map=SimpleNamespace(current_placement=lambda: placement[0]))
    run = SimpleNamespace(cfg=SlamConfig(), backend=backend,
                          sources=SimpleNamespace(camera=cam, tissue=SimpleNamespace(whole_frame=True)))
    live = LiveRun(LiveSettings(port=0, linger=0), run.cfg, echo=lambda line: None)
    live.source = SimpleNamespace(describe=lambda: {"kind": "folder", "name": "x", "rate_fps": None},
                                  captured_at=lambda i: None, take_dropped=list, delivery_rate=lambda: None,
                                  dropped=0)
    live.opened(run)
    try:
        def step(i: int, part: int, T: np.ndarray) -> dict:
            rgb, depth = render_pinhole(scene, cam.K, T, 64, 64)
            placement[0] = (part, T)
            frame = StreamFrame(index=i, timestamp=i / 30, rgb=rgb, depth=depth, status="ok", mean_luma=100.0)
            live.stepped(run, PerceivedFrame(frame, depth), "extended", FrameDecision(i, 0, "extended"))
            return live.state.snapshot(0)

        poses = tube_views(np.arange(0.0, 0.2, 0.004))
        for i in range(30):
            snap = step(i, 0, poses[i])
        rows_a = len(snap["wall"]["rows"])
        assert rows_a > 0 and snap["wall"]["epoch"] == 0
        snap = step(30, 7, poses[0])  # a new part: its own frame starts at the start
        assert snap["wall"]["epoch"] == 1 and len(snap["wall"]["rows"]) == 0 and live.switches == 1
        snap = step(31, 0, poses[31])  # rejoined the first part: its wall again, all of it
        assert snap["wall"]["epoch"] == 2 and len(snap["wall"]["rows"]) >= rows_a
        assert list(live.tracks) == [7, 0] and live.switches == 2
    finally:
        live.close()
