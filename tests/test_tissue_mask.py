"""The tissue area of a real recording: the scope's border and burned-in overlays found from the
first frames, read from a mask file, and kept out of the network input, depth and coverage."""

from __future__ import annotations

import math
import shutil
from pathlib import Path

import cv2
import numpy as np
import open3d as o3d
import pytest

from c3f_core.errors import InputError
from c3f_slam import geometry as g
from c3f_slam.camera.intrinsics import PinholeCamera
from c3f_slam.cli.main import main
from c3f_slam.config import TissueConfig
from c3f_slam.config import preset as slam_preset
from c3f_slam.coverage.visibility import ViewSettings, in_view
from c3f_slam.frames.preprocess import fill_outside, on_grid, prepare_network_input
from c3f_slam.frames.stream import StreamFrame
from c3f_slam.frames.tissue import detect_tissue_mask, read_mask_png
from c3f_slam.io import Sequence
from c3f_slam.io.sequence import encode_depth, read_depth_png
from c3f_slam.models import DepthModel
from c3f_slam.pipeline import run_slam
from c3f_slam.pipeline.frontend import ModelDepth
from datamodules.synthetic.fixture import make_tiny_sequence
from tests.onnx_fixtures import depth_model
from tests.scenes import plane_texture, render_plane

W, H = 160, 128


def _border(shape: str, w: int = W, h: int = H) -> np.ndarray:
    """(h, w) bool: the true tissue area of a scope border ``shape``."""
    m = np.zeros((h, w), np.uint8) if shape != "none" else np.ones((h, w), np.uint8)
    cx, cy, r = (w - 1) / 2, (h - 1) / 2, 0.56 * h
    if shape == "circle":
        cv2.circle(m, (round(cx * 16), round(cy * 16)), round(r * 16), 1, -1, shift=4)
    elif shape == "octagon":
        pts = [(cx + r * math.cos(a), cy + r * math.sin(a)) for a in np.arange(8) * math.pi / 4 + math.pi / 8]
        cv2.fillConvexPoly(m, np.round(np.array(pts) * 16).astype(np.int32), 1, shift=4)
    elif shape == "cut_corners":
        c = 0.2 * h
        pts = [(c, 0), (w - 1 - c, 0), (w - 1, c), (w - 1, h - 1 - c), (w - 1 - c, h - 1), (c, h - 1), (0, h - 1 - c),
               (0, c)]
        cv2.fillConvexPoly(m, np.round(np.array(pts) * 16).astype(np.int32), 1, shift=4)
    elif shape == "letterbox":
        m[int(0.12 * h):int(0.88 * h)] = 1
    return m.astype(bool)


def _clock(frame: int, fps: float = 25.0) -> str:
    s = int(frame / fps)
    return f"12:{s // 60:02d}:{s % 60:02d}"


def _frames(shape: str, n: int = 60, overlay: bool = True, seed: int = 0) -> tuple[list[np.ndarray], np.ndarray]:
    """A textured plane seen by a camera moving sideways and turning, with the border ``shape``
    (dark, with compression-like noise) and burned-in text: a label in the border, a running clock
    and an icon over the tissue. Returns the frames and the overlay pixels over the tissue."""
    cam = PinholeCamera.from_fov(W, H, 90.0)
    tex = plane_texture(seed=seed)
    rng = np.random.default_rng(seed)
    truth = _border(shape)
    frames, over_tissue = [], np.zeros((H, W), bool)
    for i in range(n):
        T = g.make_pose(g.axis_angle_to_matrix([0.0, 0.004 * i, 0.01 * i]), [0.0015 * i, 0.0005 * i, 0.0])
        img, _ = render_plane(cam, T, tex, 0.05, extent=0.1)
        img = img.copy()
        img[~truth] = rng.integers(0, 9, size=(int((~truth).sum()), 3), dtype=np.uint8)
        if overlay:
            text = np.zeros((H, W), np.uint8)
            cv2.putText(text, "SCOPE 1", (2, 10), cv2.FONT_HERSHEY_PLAIN, 0.7, 1, 1)  # in the border
            cv2.putText(text, _clock(i), (48, 100), cv2.FONT_HERSHEY_PLAIN, 0.8, 1, 1)  # over the tissue
            cv2.rectangle(text, (100, 40), (108, 48), 1, -1)  # an icon
            img[text > 0] = 235
            over_tissue |= (text > 0) & truth
        frames.append(img)
    return frames, over_tissue


def _boundary_distance(mask: np.ndarray) -> np.ndarray:
    """Distance (px) of every pixel to the edge of ``mask``."""
    inside = cv2.distanceTransform(mask.astype(np.uint8), cv2.DIST_L2, 3)
    outside = cv2.distanceTransform((~mask).astype(np.uint8), cv2.DIST_L2, 3)
    return np.maximum(inside, outside)


@pytest.mark.parametrize("shape", ["circle", "octagon", "cut_corners", "letterbox"])
def test_the_border_is_found_within_a_few_pixels(shape):
    frames, over_tissue = _frames(shape, overlay=False)
    cfg = TissueConfig()
    found = detect_tissue_mask(frames, cfg)
    truth = _border(shape)
    assert found.source == "detected" and found.frames == len(frames)
    margin = round(cfg.margin * min(W, H))
    edge = _boundary_distance(truth)
    assert edge[found.pixels & ~truth].max(initial=0) <= 1  # nothing of the border beyond the edge's pixel
    assert edge[truth & ~found.pixels].max() <= margin + 2  # the misses are the margin at the edge
    assert abs(found.share - truth.mean()) < 0.06


def test_overlays_are_left_out_and_a_running_clock_counts_as_overlay():
    frames, over_tissue = _frames("octagon")
    found = detect_tissue_mask(frames, TissueConfig())
    assert found.overlay_share > 0
    assert not (found.pixels & over_tissue).any()  # the clock and the icon are not tissue
    truth = _border("octagon") & ~over_tissue
    assert found.pixels.sum() > 0.9 * truth.sum()  # and little else is lost
    assert _boundary_distance(truth)[found.pixels & ~_border("octagon")].max(initial=0) <= 1  # nor the label


def test_frames_without_a_border_use_the_whole_frame():
    frames, _ = _frames("none", overlay=False)
    found = detect_tissue_mask([np.ascontiguousarray(f) for f in frames], TissueConfig())
    assert found.pixels.all() and found.source.startswith("whole frame")


def test_a_scope_held_still_gives_the_border_alone():
    frames, _ = _frames("circle", n=2, overlay=False)
    found = detect_tissue_mask([frames[0]] * 20, TissueConfig())
    assert found.source.startswith("detected (border only")
    truth = _border("circle")
    assert _boundary_distance(truth)[found.pixels & ~truth].max(initial=0) <= 1
    assert found.share > 0.9 * truth.mean()


def test_the_network_sees_no_black_border_and_the_tissue_unchanged():
    frames, _ = _frames("circle", n=1, overlay=False)
    truth = _border("circle")
    cam = PinholeCamera.from_fov(W, H, 90.0)
    filled = fill_outside(frames[0], truth)
    assert np.array_equal(filled[truth], frames[0][truth])
    luma = cv2.cvtColor(filled, cv2.COLOR_RGB2GRAY)
    assert luma[~truth].min() > 40  # the plane's texture is bright; the border took its colours
    net, _, net_cam = prepare_network_input(frames[0], cam, crop=(128, 128), size=(64, 64), specular=False,
                                            tissue=truth)
    plain, _, _ = prepare_network_input(frames[0], cam, crop=(128, 128), size=(64, 64), specular=False)
    grid = on_grid(truth, ((W - 128) // 2, 0, 128, 128), (64, 64))
    assert (net_cam.width, net_cam.height) == (64, 64) and np.array_equal(net[grid], plain[grid])
    assert cv2.cvtColor(net, cv2.COLOR_RGB2GRAY)[~grid].min() > 40
    assert cv2.cvtColor(plain, cv2.COLOR_RGB2GRAY)[~grid].min() < 10  # what the net saw before


def test_coverage_counts_only_points_seen_inside_the_mask():
    cam = PinholeCamera.from_fov(W, H, 90.0)
    v, u = np.mgrid[0:H, 0:W]
    z = np.full(u.size, 0.05)
    pts = np.stack([(u.ravel() - cam.cx) / cam.fx * z, (v.ravel() - cam.cy) / cam.fy * z, z], axis=1)
    mask = _border("octagon")
    plain = in_view(pts, np.eye(4), cam.K, ViewSettings(width=W, height=H, depth_min=0.01, depth_max=0.1))
    masked = in_view(pts, np.eye(4), cam.K, ViewSettings(width=W, height=H, depth_min=0.01, depth_max=0.1, mask=mask))
    assert plain.all() and np.array_equal(masked, mask.ravel())


def test_a_mask_file_of_the_wrong_size_or_empty_is_refused_in_one_line(tmp_path):
    good = tmp_path / "mask.png"
    cv2.imwrite(str(good), _border("circle").astype(np.uint8) * 255)
    assert np.array_equal(read_mask_png(good, W, H), _border("circle"))
    cv2.imwrite(str(tmp_path / "small.png"), np.full((H // 2, W // 2), 255, np.uint8))
    cv2.imwrite(str(tmp_path / "empty.png"), np.zeros((H, W), np.uint8))
    (tmp_path / "text.png").write_text("not an image")
    for name, words in [("small.png", f"is {W // 2}x{H // 2} but the frames are {W}x{H}"), ("empty.png", "is empty"),
                        ("text.png", "not a readable image"), ("missing.png", "not found")]:
        with pytest.raises(InputError) as err:
            read_mask_png(tmp_path / name, W, H, "tissue.file")
        assert words in str(err.value) and name in str(err.value) and "\n" not in str(err.value)


@pytest.mark.parametrize("field, value", [("mode", "sometimes"), ("frames", 1), ("moving_share", 0.0),
                                          ("margin", 0.3), ("full_share", 1.5)])
def test_bad_tissue_settings_name_the_field(field, value):
    with pytest.raises(InputError, match=f"tissue.{field}"):
        TissueConfig(**{field: value})


# ---------------------------------------------------------------------- end to end on the simulator

@pytest.fixture(scope="module")
def scoped(tmp_path_factory) -> Path:
    """A tiny simulated sequence seen through an octagonal scope border with burned-in text."""
    return make_tiny_sequence(tmp_path_factory.mktemp("tissue") / "seq", frames=24, size=128, seed=3,
                              **{"nuisance.border": "octagon", "nuisance.overlay": True})


@pytest.fixture(scope="module")
def depth_onnx(tmp_path_factory) -> Path:
    """A closed-form depth model: it predicts depth everywhere, the border too."""
    return depth_model(tmp_path_factory.mktemp("onnx") / "depth.onnx", size=(64, 64))


def _dark_vertex_share(mesh_path: Path) -> float:
    colours = np.asarray(o3d.io.read_triangle_mesh(str(mesh_path)).vertex_colors)
    return float(((colours @ np.array([0.299, 0.587, 0.114])) * 255 < 20).mean())


def _with_border_depth(seq: Path, out: Path, depth_m: float = 0.03) -> Path:
    """A copy of ``seq`` whose depth files also give the border a depth (as a network does)."""
    shutil.copytree(seq, out)
    s = Sequence(out)
    for path in s.depth_paths:
        d = read_depth_png(path, s.camera.depth_scale)
        cv2.imwrite(str(path), encode_depth(np.where(d > 0, d, np.float32(depth_m)), s.camera.depth_scale))
    return out


def test_the_simulators_border_is_found_and_kept_out_of_the_map(scoped, tmp_path):
    truth = read_mask_png(scoped / "tissue_mask.png", 128, 128)
    seq = _with_border_depth(scoped, tmp_path / "seq")
    cfg = slam_preset("colon", fragments={"min_correspondences": 15}, coverage={"enabled": False})
    s = run_slam(seq, tmp_path / "masked", cfg, progress=False)
    found = read_mask_png(tmp_path / "masked" / "tissue_mask.png", 128, 128)
    assert s["tissue_mask"]["source"] == "detected" and s["tissue_mask"]["share"] == pytest.approx(found.mean(), 1e-3)
    assert _boundary_distance(truth)[found & ~truth].max(initial=0) <= 1  # none of the border
    assert found.sum() > 0.85 * truth.sum()
    assert s["registered_share"] > 0.9 and _dark_vertex_share(tmp_path / "masked" / "mesh.ply") == 0.0
    off = run_slam(seq, tmp_path / "off", cfg.with_(tissue={"mode": "off"}), progress=False)
    assert off["tissue_mask"]["source"] == "whole frame" and off["tissue_mask"]["share"] == 1.0
    assert _dark_vertex_share(tmp_path / "off" / "mesh.ply") > 0.05  # without the mask the border is surface


def test_model_depth_is_zero_outside_the_tissue_on_both_grids(scoped, depth_onnx):
    seq = Sequence(scoped)
    truth = read_mask_png(scoped / "tissue_mask.png", 128, 128)
    depth = ModelDepth(DepthModel(depth_onnx), seq.camera, tissue=truth)
    frame = StreamFrame(index=0, timestamp=0.0, rgb=seq.read_rgb(0), depth=None, status="ok", mean_luma=100.0)
    pred = depth.predict(frame)
    grid = on_grid(truth, (0, 0, 128, 128), (64, 64))
    assert (pred.frame[~truth] == 0).all() and (pred.frame[truth] > 0).mean() > 0.99
    assert (pred.network[~grid] == 0).all() and (pred.network[grid] > 0).all()


def test_a_bad_mask_file_fails_the_run_in_one_line(scoped, tmp_path, capsys):
    cv2.imwrite(str(tmp_path / "small.png"), np.full((64, 64), 255, np.uint8))
    code = main(["run", str(scoped), "--out", str(tmp_path / "out"), "--quiet", "--set",
                 f"tissue.file={tmp_path / 'small.png'}"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1
    assert err[0].startswith("error: ") and "small.png" in err[0] and "64x64 but the frames are 128x128" in err[0]
