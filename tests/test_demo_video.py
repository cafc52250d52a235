"""The demo on a user's own video (``python -m c3f_demo --video FILE``): the ingest of a video into
a sequence folder, the report's video variant on fake inputs (no ground-truth section, the tissue
mask, the frames per cause, a per-frame log's timeline), bad input in one line, and (e2e) the whole
``--quick`` run on a tiny simulated video with a scope border."""

from __future__ import annotations

import csv
import json
import math
import re
import shutil
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from c3f_core.errors import InputError
from c3f_demo import config as demo_cfg
from c3f_demo.cli import _parser, config_of
from c3f_demo.report import SECTIONS, VIDEO_SECTIONS, build_report
from c3f_demo.report_records import Figures, Image, ReportData
from c3f_demo.video import frame_counts
from c3f_slam.camera.intrinsics import PinholeCamera
from datamodules.ingest import frame_step, ingest, read_times, target_size

ROOT = Path(__file__).resolve().parents[1]
#: sections of the simulator demo that need its ground truth
TRUTH_SECTIONS = set(SECTIONS) - set(VIDEO_SECTIONS)


def write_video(frames: list[np.ndarray], path: Path, fps: float) -> Path:
    """RGB frames as an MP4 file (OpenCV's mp4v)."""
    h, w = frames[0].shape[:2]
    vw = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), fps, (w, h))
    for f in frames:
        vw.write(cv2.cvtColor(f, cv2.COLOR_RGB2BGR))
    vw.release()
    return path


@pytest.fixture(scope="module")
def tiny_video(tmp_path_factory) -> Path:
    """20 frames of a tiny simulated colon behind an octagonal scope border, 96 px, as a 10 fps
    MP4 (2 s: the jitter ratio's 1-s average fits) with its camera.json beside it."""
    from c3f_slam.io import Sequence
    from datamodules.synthetic.fixture import make_tiny_sequence

    root = tmp_path_factory.mktemp("video")
    seq = Sequence(make_tiny_sequence(root / "seq", frames=20, size=96, seed=3, **{"nuisance.border": "octagon"}))
    folder = root / "clip"
    folder.mkdir()
    shutil.copy(seq.root / "camera.json", folder / "camera.json")
    return write_video([seq.read_rgb(i) for i in range(len(seq))], folder / "clip.mp4", 10.0)


def test_frame_step_and_size():
    assert [frame_step(fps, 30) for fps in (10, 25, 30, 50, 60, 120)] == [1, 1, 1, 2, 2, 4]
    assert target_size(446, 448, 256) == (255, 256) and target_size(1920, 1080, 256) == (256, 144)
    assert target_size(96, 96, 256) == (96, 96)  # never enlarged
    with pytest.raises(InputError):
        target_size(96, 96, 4)


def test_ingest_with_fov_guess_writes_a_sequence(tmp_path):
    """Every 2nd frame of a 60 fps video, at most 5, halved to 48 px: camera.json follows the
    resize, frames.csv has each frame's time in the video; the folder is a sequence."""
    from c3f_slam.io import Sequence

    rng = np.random.default_rng(0)
    video = write_video([rng.integers(0, 255, (96, 96, 3), np.uint8) for _ in range(12)], tmp_path / "v.mp4", 60.0)
    rec = ingest(video, tmp_path / "seq", fov=100.0, max_fps=30, max_frames=5, max_side=48)
    seq = Sequence(tmp_path / "seq")
    assert len(seq) == 5 and seq.read_rgb(0).shape == (48, 48, 3) and rec["step"] == 2
    assert seq.camera.fx == pytest.approx(PinholeCamera.from_fov(96, 96, 100.0).resize(48, 48).fx)
    assert read_times(tmp_path / "seq") == pytest.approx({k: 2 * k / 60 for k in range(5)}, abs=1e-6)  # µs
    assert "fov guess 100 deg" in rec["camera_source"]
    with pytest.raises(InputError, match="not empty"):
        ingest(video, tmp_path / "seq", fov=100.0)
    assert not list(tmp_path.glob(".seq.partial-*"))  # no staging folder left


def test_ingest_drops_repeats_keeps_video_times_and_records_the_tissue_area(tiny_video, tmp_path):
    """A re-encoded video that shows each picture twice: the repeats are not written, each frame
    keeps its time in the video (times.txt: what the runtime's motion prior and jitter ratio read),
    and the scope's border is found once and named by camera.json, where the runtime and the
    training data modules read it."""
    from c3f_slam.frames.tissue import camera_mask_file, read_mask_png
    from c3f_slam.io import Sequence

    cap, frames = cv2.VideoCapture(str(tiny_video)), []
    while (ok_frame := cap.read())[0]:
        frames.append(cv2.cvtColor(ok_frame[1], cv2.COLOR_BGR2RGB))
    cap.release()
    doubled = write_video([f for f in frames for _ in range(2)], tmp_path / "doubled.mp4", 20.0)
    shutil.copy(tiny_video.parent / "camera.json", tmp_path / "camera.json")
    rec = ingest(doubled, tmp_path / "seq", max_fps=30, max_side=96)
    seq = Sequence(tmp_path / "seq")
    assert rec["repeats_dropped"] >= 15 and len(seq) == 2 * len(frames) - rec["repeats_dropped"]
    assert seq.timestamps is not None and seq.timestamps[-1] == pytest.approx(rec["seconds"] + seq.timestamps[0])
    assert np.all(np.diff(seq.timestamps) >= 1 / 20 - 1e-6)  # a kept frame every 1/20 s or more
    mask = read_mask_png(camera_mask_file(seq.root / "camera.json"), seq.camera.width, seq.camera.height)
    assert 0.5 < mask.mean() < 0.95 and rec["tissue_mask"]["file"] == "tissue_mask.png"
    assert not mask[0, 0] and mask[48, 48]  # the octagon's corner is border, the centre tissue


def test_a_sequence_reads_its_times_and_refuses_bad_ones_in_one_line(tmp_path):
    from c3f_slam.io import Sequence, SequenceWriter

    writer = SequenceWriter(tmp_path / "s", PinholeCamera(8, 8, 8.0, 8.0, 3.5, 3.5))
    for k in range(3):
        writer.write_frame(k, np.zeros((8, 8, 3), np.uint8))
    writer.finish(timestamps=np.array([0.5, 0.55, 0.65]))
    assert Sequence(tmp_path / "s").timestamps == pytest.approx([0.5, 0.55, 0.65])
    for text, why in (("0.5\n0.55\n", "2 times for 3 frames"), ("0.5\n0.5\n0.6\n", "increase"),
                      ("0.5\nx\n0.6\n", "not a list of times")):
        (tmp_path / "s" / "times.txt").write_text(text)
        with pytest.raises(InputError, match=why):
            Sequence(tmp_path / "s")


def test_options_of_a_video(tmp_path):
    """The camera.json beside the video is taken when neither --camera nor --fov is given."""
    video = tmp_path / "v.mp4"
    video.write_bytes(b"")
    cfg = config_of(_parser().parse_args(["--video", str(video), "--fov", "90", "--out", "o", "--quick"]))
    assert cfg.video.fov == 90 and cfg.video.camera is None and cfg.simulate is None and cfg.ttt.steps == 3
    (tmp_path / "camera.json").write_text("{}")
    cfg = config_of(_parser().parse_args(["--video", str(video), "--out", "o"]))
    assert cfg.video.camera == str(tmp_path / "camera.json") and cfg.video.max_side == 256
    for bad in (["--fov", "90"], ["--video", str(video), "--from-scratch"]):
        with pytest.raises(InputError):
            config_of(_parser().parse_args([*bad, "--out", "o"]))


def _png_bytes() -> bytes:
    return cv2.imencode(".png", np.full((8, 12, 3), 128, np.uint8))[1].tobytes()


def fake_video_inputs() -> tuple[ReportData, Figures]:
    """What the video report's collect and figures steps give, in memory: one run ok (tissue mask,
    frames per cause), one failed."""
    images = {p: Image(p, _png_bytes()) for p in ("figures/tissue_mask.png", "figures/frames_paper.png",
                                                  "figures/mesh_paper_side.png", "slam/paper/coverage_map.png",
                                                  "slam/paper/keyframe_graph.png")}
    summary = {"frames": 30, "processed": 27, "registered_frames": 25, "skipped_black": 2, "skipped_blurred": 1,
               "skipped_saturated": 0}
    paper = {"title": "predicted depth after TTT + ContraFeat", "status": "ok", **summary, "registered_share": 25 / 30,
             "frame_decisions": {"extended": 20, "keyframe": 5}, "skipped": {"black": 2, "blurred": 1},
             "frame_counts": frame_counts(summary), "jitter_ratio": 1.234, "path_length_m": 0.05, "seconds": 2.0,
             "unseen_share": 0.3, "tissue_mask": {"share": 0.876, "source": "detected", "frames": 20,
                                                  "overlay_share": 0.01}}
    failed = {"title": "predicted depth without TTT + ContraFeat", "status": "failed",
              "error": "error: no frame could be registered (exit 2)"}
    cfg = demo_cfg.video_config("/data/clip.mp4", fov=110.0, quick=True)
    ingested = {"video": "/data/clip.mp4", "fps": 60.0, "video_frames": 120, "step": 2, "frames": 30, "seconds": 1.0,
                "source_size": [446, 448], "size": [255, 256], "camera_source": "fov guess 110 deg",
                "camera": {"width": 255, "fx": 89.3, "fy": 89.3, "cx": 127, "cy": 127.5},
                "statuses": {"ok": 28, "black": 2}, "settings": {"max_fps": 30, "max_frames": 600}}
    unseen = {"source": "run", "runs": [{"run": paper["title"], "status": "ok", "unseen_share": 0.3,
                                         "map": "slam/paper/coverage_map.png",
                                         "segments": [{"start_m": 0, "end_m": 0.05, "unseen_share": 0.3}]}]}
    data = ReportData("video", cfg.as_dict(), {"slam": {"paper": paper, "no_ttt": failed}}, [("ingest", 1.0, "ran")],
                      {"python": "3.11"}, ingest=ingested, unseen=unseen)
    figs = Figures(images=images, meshes={"paper": ["mesh_paper_side.png"]},
                   tissue={"frame": 15, "figure": "tissue_mask.png"},
                   frames={"paper": {"kind": "counts", "figure": "frames_paper.png"}})
    return data, figs


def test_video_report_has_no_ground_truth_sections():
    """The video variant: its sections in order, none of the demo's ground-truth ones and no ATE;
    the mask's share and source, the skipped frames by cause, the jitter ratio, the unseen share
    with the sentence on what they cannot mean; every image embedded; a failed run said plainly."""
    html = build_report(*fake_video_inputs())
    ids = re.findall(r'<section id="([^"]+)">', html)
    assert ids == list(VIDEO_SECTIONS) and not TRUTH_SECTIONS & set(ids)
    assert not re.search(r"\bATE\b", html) and "no truth measured" not in html
    assert "87.6" in html and "detected" in html  # the tissue mask's share and source
    assert "black 2" in html and "blurred 1" in html and "1.23" in html and "30.0 %" in html
    assert "describe the map, not its accuracy" in html and "a guess from the field of view" in html
    assert "FAILED" in html and "no frame could be registered" in html
    assert html.count("data:image/png;base64,") == 5 and "http" not in html


def test_frame_log_is_drawn_as_a_timeline(tmp_path):
    """A run folder with a per-frame log (index, timestamp, outcome: the skip cause or else the
    decision, as the runtime's FrameLog writes it, rows in any order): one label per frame, in the
    frames' order; without it, the counts. The figures step draws each strip and hands on the
    file's bytes."""
    from c3f_demo.collect import frame_labels
    from c3f_demo.context import DemoContext
    from c3f_demo.figures import make_figures

    ctx = DemoContext(tmp_path, demo_cfg.video_config("/v.mp4", fov=90.0, quick=True))
    run = ctx.slam_dir("paper")
    run.mkdir(parents=True)
    rows = [(1, 0.1, "extended"), (0, 0.0, "lone"), (2, 0.2, "blurred"), (3, 0.3, "extended")]
    with (run / "frame_log.csv").open("w", newline="") as fh:
        csv.writer(fh).writerows([("index", "timestamp", "outcome"), *rows])
    slam = {"paper": {"frame_counts": {"registered": 3, "blurred": 1}},
            "no_ttt": {"frame_counts": {"registered": 2, "not registered": 2}}}
    labels = frame_labels(ctx, slam)
    assert labels["paper"] == ("timeline", ["lone", "extended", "blurred", "extended"])
    figs = make_figures(ReportData("video", ctx.cfg.as_dict(), {"slam": slam}, [], {}, frame_labels=labels), tmp_path)
    assert figs.frames["paper"]["kind"] == "timeline"
    assert figs.frames["paper"]["counts"] == {"lone": 1, "extended": 2, "blurred": 1}
    assert figs.frames["no_ttt"]["kind"] == "counts"
    assert figs.frames["no_ttt"]["counts"] == {"registered": 2, "not registered": 2}
    strip = cv2.imread(str(tmp_path / "figures" / "frames_paper.png"))
    assert strip is not None and strip.shape[1] == 900
    assert figs.image("figures/frames_paper.png").png == (tmp_path / "figures" / "frames_paper.png").read_bytes()


def _demo(*args: str, timeout: float = 600) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "c3f_demo", *args], cwd=ROOT, capture_output=True, text=True,
                          timeout=timeout)


@pytest.mark.e2e
def test_video_without_intrinsics_or_missing_is_one_line(tmp_path, tiny_video):
    """A missing video, and a video with no camera.json beside it and no --fov: exit 2, one line,
    nothing written."""
    bare = tmp_path / "bare.mp4"
    shutil.copy(tiny_video, bare)
    for video, said in ((tmp_path / "missing.mp4", "no such file"), (bare, "no intrinsics")):
        r = _demo("--video", str(video), "--out", str(tmp_path / "out"), "--quick", timeout=120)
        assert r.returncode == 2 and r.stderr.count("\n") == 1 and said in r.stderr, r.stderr
    assert not (tmp_path / "out").exists()


@pytest.mark.e2e
@pytest.mark.long
def test_quick_video_end_to_end(tmp_path, tiny_video):
    """``--video`` (camera.json beside it) ``--quick``: every stage ran; the frames became a
    sequence; both runs' numbers; the report has the mask section, the 3D view and no
    ground-truth section; a rerun skips every stage."""
    out = tmp_path / "out"
    r = _demo("--video", str(tiny_video), "--out", str(out), "--quick")
    assert r.returncode == 0, r.stderr[-2000:]
    assert len(list((out / "data" / "video" / "rgb").glob("*.png"))) == 20
    assert (out / "runs/depthnet_ttt/tb/version_0/checkpoints/guard.json").is_file()
    slam = json.loads((out / "metrics" / "slam.json").read_text())
    assert set(slam) == {"paper", "no_ttt"} and slam["paper"]["status"] == "ok", slam
    paper = slam["paper"]
    # found once by the ingest, named by the sequence's camera.json, read there by both runs
    ingest = json.loads((out / "data" / "video" / "ingest.json").read_text())
    assert ingest["tissue_mask"]["source"] == "detected" and paper["tissue_mask"]["source"] == "camera.json"
    assert 0.5 < paper["tissue_mask"]["share"] < 0.99
    assert 0 < paper["registered_share"] <= 1 and math.isfinite(paper["jitter_ratio"]) and paper["jitter_ratio"] > 0
    html = (out / "report.html").read_text()
    ids = re.findall(r'<section id="([^"]+)">', html)
    assert ids == list(VIDEO_SECTIONS) and not TRUTH_SECTIONS & set(ids)
    assert "outside the tissue area tinted magenta" in html and 'class="c3f-view"' in html
    assert (out / "slam" / "paper" / "view.html").is_file() and "data:video/mp4;base64," in html
    again = _demo("--video", str(tiny_video), "--out", str(out), "--quick", timeout=120)
    assert again.returncode == 0 and again.stdout.count("skipped: done earlier") == 8, again.stdout
