"""`python -m c3f_slam view OUT`: the 3D view page, the re-rendered video and the fly-through.

The re-rendered depth from a registered pose matches the simulator's true depth; the page opens
in headless Chromium with the network off, draws, and every layer toggles (tests/browser.py);
the settings (--set, --config, --print-config) reach the page and the videos, bad ones are one
line (their replay from view.json: tests/test_replay.py).
"""

from __future__ import annotations

import base64
import json
import re
import shutil
from dataclasses import fields, is_dataclass
from pathlib import Path

import cv2
import numpy as np
import open3d as o3d
import pytest
import yaml

from c3f_core.errors import InputError
from c3f_core.settings import field_docs, tree_as_mapping
from c3f_slam.cli.main import main
from c3f_slam.coverage.render import UNSEEN_COLOUR
from c3f_slam.io import Sequence, read_tum
from c3f_slam.io.sequence import read_depth_png
from c3f_slam.view.budget import ViewBudget, decimate
from c3f_slam.view.flythrough import smoothed_path
from c3f_slam.view.layers import frusta, triangles_coloured
from c3f_slam.view.raycast import MeshScene, render_pinhole, scale_intrinsics
from c3f_slam.view.rerender import PoseLookup, RenderClock, rerender_frames
from c3f_slam.view.scene import run_layers
from c3f_slam.view.settings import REPORT_BUDGET, FlythroughSettings, VideoSettings, ViewSettings
from datamodules.synthetic.fixture import make_tiny_sequence
from tests import browser
from tests.bad_input import fingerprint
from tests.scenes import tube_mesh

RUN = ["--set", "fragments.min_correspondences=15", "--quiet"]


@pytest.fixture(scope="module")
def evaluated(tmp_path_factory) -> tuple[Path, Path]:
    """(sequence, run folder): 16 simulator frames at 128 px, RGB-D run, evaluated."""
    root = tmp_path_factory.mktemp("view")
    seq = make_tiny_sequence(root / "seq", frames=16, size=128, seed=3)
    assert main(["run", str(seq), "--out", str(root / "out"), *RUN]) == 0
    assert main(["evaluate", str(root / "out"), "--gt", str(seq)]) == 0
    return seq, root / "out"


@pytest.fixture(scope="module")
def viewed(evaluated, tmp_path_factory) -> Path:
    """A copy of the run with a component beside the main map, then `view` of it."""
    out = tmp_path_factory.mktemp("viewed") / "out"
    shutil.copytree(evaluated[1], out)
    comp = out / "components" / "01"
    comp.mkdir(parents=True)
    for name in ("mesh.ply", "trajectory.txt"):
        shutil.copy(out / name, comp / name)
    summary = json.loads((out / "summary.json").read_text())
    summary["components"].append({"id": 1, "main": False, "frames": 16, "files": [
        "components/01/mesh.ply", "components/01/trajectory.txt"]})
    (out / "summary.json").write_text(json.dumps(summary))
    assert main(["view", str(out), "--no-open", "--quiet"]) == 0
    return out


def test_scaled_intrinsics_keep_pixel_centres():
    """A point at pixel (u, v) lands at f (u + 0.5) - 0.5 in the image f times as large."""
    K = np.array([[40.0, 0, 31.5], [0, 40.0, 23.5], [0, 0, 1]])
    p = np.array([0.01, -0.02, 0.1])
    uv = (K @ p)[:2] / p[2]
    uv3 = (scale_intrinsics(K, 3) @ p)[:2] / p[2]
    assert np.allclose(uv3, 3 * (uv + 0.5) - 0.5)


def test_render_depth_of_a_tube_from_its_axis():
    """On the axis of a tube of radius 2.5 cm (open ends), looking along it: each pixel sees the
    wall at depth R / tan(angle off the axis), or nothing when that is beyond the tube's end."""
    from c3f_slam.camera.intrinsics import PinholeCamera
    from c3f_slam.geometry import look_at

    cam = PinholeCamera.from_fov(32, 32, 60.0)
    T = look_at([0, 0, 0.05], [0, 0, 0.09], [0, 1.0, 0])
    rgb, depth = render_pinhole(MeshScene.of(tube_mesh()), cam.K, T, 32, 32)
    u = np.arange(32) - cam.cx
    x, y = np.meshgrid(u / cam.fx, u / cam.fy)
    expect = 0.025 / np.hypot(x, y)
    wall = expect < 0.07  # the tube ends 7 cm ahead
    assert rgb.shape == (32, 32, 3) and 0.5 < wall.mean() < 1 and (depth[~wall] == 0).all()
    assert np.median(np.abs(depth[wall] - expect[wall]) / expect[wall]) < 0.01


def test_unseen_patches_and_decimation():
    mesh = tube_mesh(length=0.05)
    cols = np.asarray(mesh.vertex_colors)
    cols[: len(cols) // 4] = UNSEEN_COLOUR
    mesh.vertex_colors = o3d.utility.Vector3dVector(cols)
    patches = triangles_coloured(mesh, UNSEEN_COLOUR)
    assert 0 < len(patches.triangles) < len(mesh.triangles) / 4
    assert np.allclose(np.asarray(patches.vertex_colors), UNSEEN_COLOUR)
    small, cut = decimate(mesh, 5000)
    assert cut and len(small.triangles) <= 5000 and small.has_vertex_colors()
    assert decimate(mesh, 10**9) == (mesh, False)


def test_frusta_and_smoothed_path():
    K = np.array([[50.0, 0, 31.5], [0, 50.0, 31.5], [0, 0, 1]])
    seg = frusta(np.eye(4)[None], K, 64, 64, 0.01)
    assert seg.shape == (16, 3) and np.allclose(seg[1::4][:, 2], 0.01)  # corners 1 cm ahead
    poses = np.repeat(np.eye(4)[None], 50, axis=0)
    poses[:, 2, 3] = np.linspace(0, 0.1, 50) ** 2 * 10  # uneven speed along z
    poses[:, 0, 3] = 0.001 * np.sin(np.arange(50))  # and jitter
    eyes, ups, length = smoothed_path(poses, FlythroughSettings(frames=60))
    steps = np.linalg.norm(np.diff(eyes, axis=0), axis=1)
    assert np.allclose(steps, steps.mean(), rtol=0.05) and length == pytest.approx(0.1, rel=0.05)
    assert np.allclose(ups, [0, -1, 0], atol=1e-6)
    assert smoothed_path(np.repeat(np.eye(4)[None], 5, axis=0)) is None


def test_unregistered_frames_say_so(evaluated):
    """A frame without a pose gets a grey panel with text, a registered one a render."""
    from c3f_slam.frames.stream import open_stream

    seq, out = evaluated
    stamps, poses = read_tum(out / "trajectory.txt")
    keep = np.arange(len(stamps)) != 3
    stream = open_stream(seq, use_depth=False, max_frames=5)
    cam, ms, clock = stream.camera, MeshScene.of(o3d.io.read_triangle_mesh(str(out / "mesh.ply"))), RenderClock()
    frames = list(rerender_frames(stream, K=cam.K, width=cam.width, height=cam.height, ms=ms,
                                  lookup=PoseLookup(stamps[keep], poses[keep]),
                                  clock=clock))
    assert len(frames) == 5 and frames[0].shape == (256, 512, 3) and clock.frames == 4
    right = frames[3][40:, 256:]  # below the label
    assert np.median(right) == 40 and right.max() > 200  # grey, with the white "not registered"
    assert np.std(frames[2][40:, 256:]) > 10  # a rendered colon


def test_a_repeated_frame_shows_the_pose_it_repeats_and_a_skipped_one_its_cause(evaluated, tmp_path):
    """Frames without a pose: a repeat the gate skipped is rendered from the last registered pose
    (the same picture as the render before it), a blurred one names its cause (frame_log.csv)."""
    from c3f_slam.frames.stream import open_stream
    from c3f_slam.io.run_outputs import FrameLog

    seq, out = evaluated
    stamps, poses = read_tum(out / "trajectory.txt")
    keep = ~np.isin(np.arange(len(stamps)), [2, 4])
    log = FrameLog(tmp_path / "frame_log.csv")
    for i, outcome in enumerate(["lone", "extended", "duplicate", "extended", "blurred"]):
        log.write(i, float(stamps[i]), outcome)
    log.close()
    outcomes = FrameLog.read(tmp_path / "frame_log.csv")
    assert outcomes == {0: "lone", 1: "extended", 2: "duplicate", 3: "extended", 4: "blurred"}
    stream = open_stream(seq, use_depth=False, max_frames=5)
    cam, ms, clock = stream.camera, MeshScene.of(o3d.io.read_triangle_mesh(str(out / "mesh.ply"))), RenderClock()
    frames = list(rerender_frames(stream, K=cam.K, width=cam.width, height=cam.height, ms=ms,
                                  lookup=PoseLookup(stamps[keep], poses[keep]), clock=clock, outcomes=outcomes))
    assert clock.frames == 4  # 0, 1, the repeat 2 (from frame 1's pose) and 3; not the blurred 4
    assert np.array_equal(frames[2][40:, 256:], frames[1][40:, 256:])  # frame 1's render again
    assert np.median(frames[4][40:, 256:]) == 40  # grey panel with its cause


def test_the_rerender_shows_the_reconstruction_inside_the_tissue_area_only(evaluated):
    """With the run's tissue area (a scope's octagon, say), the reconstruction panel is black
    outside it and the same render inside it."""
    from c3f_slam.frames.stream import open_stream

    seq, out = evaluated
    stamps, poses = read_tum(out / "trajectory.txt")
    ms = MeshScene.of(o3d.io.read_triangle_mesh(str(out / "mesh.ply")))

    def panels(tissue):
        stream = open_stream(seq, use_depth=False, max_frames=3)
        cam = stream.camera
        frames = rerender_frames(stream, K=cam.K, width=cam.width, height=cam.height, ms=ms,
                                 lookup=PoseLookup(stamps, poses), clock=RenderClock(),
                                 tissue=tissue)
        return [f[:, f.shape[1] // 2:] for f in frames], cam

    plain, cam = panels(None)
    tissue = np.zeros((cam.height, cam.width), bool)
    tissue[cam.height // 8: -cam.height // 8, cam.width // 8: -cam.width // 8] = True
    masked, _ = panels(tissue)
    inside = cv2.resize(tissue.astype(np.uint8), plain[0].shape[1::-1], interpolation=cv2.INTER_NEAREST) > 0
    below = np.zeros_like(inside)
    below[40:] = True  # the panel's label is drawn over the top rows
    for a, b in zip(plain, masked):
        assert b[~inside & below].max() == 0 and a[~inside & below].max() > 0
        assert np.array_equal(a[inside & below], b[inside & below])


@pytest.mark.e2e
def test_rerendered_depth_matches_the_true_depth(evaluated):
    """From each registered pose, the fused mesh's depth (ray cast with the run's intrinsics)
    against the simulator's true depth. Measured (16 frames, 128 px): median error 0.18-0.35 mm at
    2-3 cm depth; the render covers 98-100 % of the pixels the truth has in the fusion range, 54 %
    on the first frame (its far wall was seen once) and has surface nowhere else."""
    seq, out = evaluated
    s, (stamps, poses) = Sequence(seq), read_tum(out / "trajectory.txt")
    ms, cam = MeshScene.of(o3d.io.read_triangle_mesh(str(out / "mesh.ply"))), s.camera
    medians, covered, stray = [], [], []
    for i in range(0, len(stamps), 3):
        _, depth = render_pinhole(ms, cam.K, poses[i], cam.width, cam.height)
        true = read_depth_png(s.depth_paths[i], cam.depth_scale)
        in_range = (true > 0.001) & (true < 0.2)
        both = in_range & (depth > 0)
        medians.append(np.median(np.abs(depth[both] - true[both])))
        covered.append(both.sum() / in_range.sum())
        stray.append(((depth > 0) & ~in_range).mean())
    assert np.median(medians) < 0.0007 and max(medians) < 0.0015  # metres
    assert np.median(covered) > 0.9 and max(stray) < 0.01


@pytest.mark.e2e
def test_view_writes_page_and_videos(viewed, evaluated):
    page = (viewed / "view.html").read_text()
    assert not re.search(r'(src|href)="https?:', page)  # nothing to fetch: one file, offline
    assert "three.js" in page and 'data-source="c3f-view-data"' in page
    data = json.loads(re.search(r'<script type="application/json" id="c3f-view-data">(.*?)</script>', page).group(1))
    ids = [lay["id"] for lay in data["layers"]]
    assert ids == ["surface", "unseen", "path", "keyframes", "gt_path", "gt_surface", "components", "components_path"]
    for name, n in (("rerender.mp4", 16), ("flythrough.mp4", 240)):
        cap = cv2.VideoCapture(str(viewed / name))
        assert int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) == n and cap.read()[0], name
    cap = cv2.VideoCapture(str(viewed / "rerender.mp4"))
    assert (cap.get(cv2.CAP_PROP_FRAME_WIDTH), cap.get(cv2.CAP_PROP_FRAME_HEIGHT)) == (512, 256)
    assert not list(viewed.glob(".*"))  # no temporary file left


def test_budget_decimates_and_page_alone(evaluated, tmp_path, capsys):
    """A small budget decimates the surface and says so; --no-video writes the page alone and
    needs no input; the run's own files are left as they were."""
    seq, src = evaluated
    out = tmp_path / "out"
    shutil.copytree(src, out)
    before = fingerprint(out)
    layers = {lay.id: lay for lay in run_layers(out, ViewBudget(surface=2000), gt=seq)}
    assert layers["surface"].triangles <= 2000 and "decimated; full resolution: mesh.ply" in layers["surface"].note
    shutil.move(seq, tmp_path / "moved")
    try:
        assert main(["view", str(out), "--no-video", "--no-open"]) == 0
        after = fingerprint(out)
        assert set(after) - set(before) == {"view.html", "view.json"}
        assert all(after[k] == v for k, v in before.items())
        assert main(["view", str(out), "--no-open", "--quiet"]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith("error: ") and "--sequence" in err[0], err
        assert main(["view", str(out), "--no-open", "--quiet", "--sequence", str(tmp_path / "moved")]) == 0
    finally:
        shutil.move(tmp_path / "moved", seq)


def test_bad_run_folder_is_one_line(tmp_path, capsys):
    for target in (tmp_path / "missing", tmp_path):
        assert main(["view", str(target), "--no-open"]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith("error: ") and str(target) in err[0], err


@pytest.mark.e2e
def test_page_draws_and_every_layer_toggles_in_chromium(viewed):
    res = browser.selftest(viewed / "view.html")
    assert res["errors"] == []
    (view,) = res["views"]
    assert view["drawn"] > 0.02 * view["pixels"]
    assert set(view["layers"]) == {"surface", "unseen", "path", "keyframes", "gt_path", "gt_surface", "components",
                                   "components_path", "cut"}
    for name, r in view["layers"].items():
        assert r["changed"] > 0 and r["restored"], (name, r)
    assert [(v["src"], v["error"]) for v in res["videos"]] == [("rerender.mp4", None), ("flythrough.mp4", None)]
    assert all(v["width"] > 0 for v in res["videos"])  # Chromium decodes the H.264


def test_a_video_run_is_rerendered_through_the_lens_it_was_read_with(tmp_path):
    """The video a run undistorted is read through the same camera.json again (summary.json's
    camera_source), so the input panel shows the frames the run saw; a pinhole camera, a guess or
    a camera file that is gone give the run's pinhole camera."""
    from c3f_slam.view.build import _lens_file

    cam = tmp_path / "camera.json"
    cam.write_text("{}")
    distorted = f"file {cam} (fisheye lens with distortion [0.1, 0.0, 0.0, 0.0], frames undistorted to pinhole)"
    assert _lens_file({"camera_source": distorted}) == cam
    assert _lens_file({"camera_source": f"file {cam}"}) is None
    assert _lens_file({"camera_source": "fov guess 110 deg"}) is None
    assert _lens_file({"camera_source": distorted.replace(str(cam), str(tmp_path / "gone.json"))}) is None


# ---------------------------------------------------------------------- settings


def test_every_view_setting_has_a_meaning_and_print_config_reads_back(tmp_path, capsys):
    """Each leaf of the tree carries a ``#:`` comment; --print-config's YAML, given back with
    --config, is the same tree; the report's budget is one of the same class, smaller."""
    tree = ViewSettings()
    for group in fields(tree):
        value = getattr(tree, group.name)
        assert is_dataclass(value) and set(field_docs(type(value))) == {f.name for f in fields(value)}, group.name
    assert main(["view", "--print-config"]) == 0
    text = capsys.readouterr().out
    assert "fov_deg: 100.0  # float: horizontal field of view (degrees)" in text
    (tmp_path / "view.yaml").write_text(text)
    assert main(["view", "--config", str(tmp_path / "view.yaml"), "--print-config"]) == 0
    assert yaml.safe_load(capsys.readouterr().out) == yaml.safe_load(text) == tree_as_mapping(tree)
    assert REPORT_BUDGET.triangles == 105_000 < tree.budget.triangles == 250_000


@pytest.mark.parametrize(("item", "where"), [
    ("budget.surface=0", "budget.surface"), ("video.fps=-1", "video.fps"), ("video.crf=60", "video.crf"),
    ("flythrough.fov_deg=180", "flythrough.fov_deg"), ("flythrough.smooth_share=0", "flythrough.smooth_share"),
    ("flythrough.width=8", "flythrough.width"), ("flythrough.frames=1.5", "flythrough.frames"),
    ("flythrough.speed=2", "flythrough.speed"), ("video.fps=nan", "video.fps")])
def test_a_bad_view_setting_is_one_line_naming_it_and_nothing_is_written(item, where, evaluated, capsys):
    out = evaluated[1]
    before = fingerprint(out)
    assert main(["view", str(out), "--no-open", "--quiet", "--set", item]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: --set: ") and where in err[0], err
    assert fingerprint(out) == before


def test_groups_check_themselves():
    for make, where in ((lambda: VideoSettings(fps=float("inf")), "video.fps"),
                        (lambda: FlythroughSettings(height=True), "flythrough.height"),
                        (lambda: ViewBudget(unseen=-5), "budget.unseen")):
        with pytest.raises(InputError, match=where):
            make()


def test_settings_reach_the_page_and_the_videos(evaluated, tmp_path, capsys):
    """--set of the budget, the videos' frame rate and the fly-through's size and length change
    the files ``view`` writes, and view.json records them."""
    seq, src = evaluated
    out = tmp_path / "out"
    shutil.copytree(src, out)
    sets = ["budget.surface=2000", "video.fps=10", "flythrough.frames=20", "flythrough.width=96",
            "flythrough.height=64", "flythrough.fov_deg=80"]
    assert main(["view", str(out), "--no-open", "--quiet", *[a for s in sets for a in ("--set", s)]]) == 0
    assert f"{out / 'view.json'}: the settings used" in capsys.readouterr().out
    page = (out / "view.html").read_text()
    data = json.loads(re.search(r'<script type="application/json" id="c3f-view-data">(.*?)</script>', page).group(1))
    surface = next(lay for lay in data["layers"] if lay["id"] == "surface")
    assert 0 < len(base64.b64decode(surface["indices"])) // 12 <= 2000 and "decimated" in surface["note"]
    cap = cv2.VideoCapture(str(out / "flythrough.mp4"))
    assert int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) == 20 and cap.get(cv2.CAP_PROP_FPS) == pytest.approx(10)
    assert (cap.get(cv2.CAP_PROP_FRAME_WIDTH), cap.get(cv2.CAP_PROP_FRAME_HEIGHT)) == (96, 64)
    assert cv2.VideoCapture(str(out / "rerender.mp4")).get(cv2.CAP_PROP_FPS) == pytest.approx(10)
    record = json.loads((out / "view.json").read_text())
    assert record["settings"]["flythrough"] == {"width": 96, "height": 64, "fov_deg": 80.0, "frames": 20,
                                                "smooth_share": 0.03, "samples": 600}
    assert record["settings"]["budget"]["surface"] == 2000 and record["settings"]["video"]["fps"] == 10.0
    assert record["files"] == ["view.html", "rerender.mp4", "flythrough.mp4", "view.json"]
    assert record["videos"]["flythrough.mp4"]["frames"] == 20 and record["with_videos"] is True
