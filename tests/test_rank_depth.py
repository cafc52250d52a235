"""Real-frame depth evaluation: the rank metric (:mod:`c3f_slam.evaluation.rank_depth`), the
phantom-folder reader (:mod:`datamodules.phantom`, on a tiny fake folder in split.py's
layout) and the zoo protocol's ``real`` section without ``--phantom``. Fast, no torch."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from c3f_core.errors import InputError
from c3f_slam.evaluation.rank_depth import luminance_depth, outside_share, rank_depth, spearman


def _depth(seed: int = 0, shape: tuple[int, int] = (24, 20)) -> np.ndarray:
    return np.random.default_rng(seed).uniform(0.01, 0.1, shape).astype(np.float32)


def test_identical_depth_is_one_and_reversed_is_minus_one():
    d = _depth()
    assert spearman(d, d) == pytest.approx(1.0)
    assert spearman(-d, d) == pytest.approx(-1.0)
    assert spearman(1.0 / d, d) == pytest.approx(-1.0)  # nearer-is-larger: the other sense


def test_a_monotone_transform_leaves_it_unchanged():
    pred, ref = _depth(1), _depth(2)
    noisy = ref + 0.5 * pred  # correlated but not identical
    rho = spearman(noisy, ref)
    assert -1.0 < rho < 1.0
    assert spearman(3.0 * noisy + 7.0, ref) == pytest.approx(rho)
    assert spearman(np.exp(40 * noisy), ref) == pytest.approx(rho)
    grey = np.round(255 * (ref - ref.min()) / np.ptp(ref))  # an 8-bit render of the reference: ties
    assert spearman(noisy, np.sqrt(grey)) == pytest.approx(spearman(noisy, grey))


def test_masked_and_undefined_pixels_are_ignored():
    ref = _depth(3)
    pred = ref.copy()
    mask = np.zeros(ref.shape, bool)
    mask[4:18, 3:15] = True
    pred[~mask] = np.random.default_rng(4).uniform(0, 1, (~mask).sum())  # wrong everywhere outside
    assert spearman(pred, ref) < 0.9
    assert spearman(pred, ref, mask) == pytest.approx(1.0)
    ref_holes = ref.copy()
    ref_holes[5, 5] = np.nan  # no reference depth there
    pred[5, 5] = -1e6
    assert spearman(pred, ref_holes, mask) == pytest.approx(1.0)
    assert spearman(pred, ref, np.zeros(ref.shape, bool)) is None  # nothing counted
    assert spearman(np.ones_like(ref), ref) is None  # a flat prediction orders nothing


def test_rank_depth_per_frame_and_pooled():
    refs = [_depth(5), _depth(6)]
    masks = [np.ones(refs[0].shape, bool), np.zeros(refs[0].shape, bool)]
    masks[1][:4] = True
    out = rank_depth([refs[0], -refs[1]], refs, masks)
    assert out["per_frame"] == pytest.approx([1.0, -1.0])
    assert out["mean"] == pytest.approx(0.0) and out["pixels"] == [refs[0].size, 4 * refs[0].shape[1]]
    assert -1.0 < out["pooled"] < 1.0
    with pytest.raises(InputError):
        rank_depth([refs[0]], refs, masks)
    with pytest.raises(InputError, match="mask"):
        spearman(refs[0], refs[0], np.ones((3, 3), bool))


def test_darker_is_farther_and_depth_outside_the_tissue():
    rgb = np.zeros((40, 40, 3), np.uint8)
    rgb[:, :20] = 200  # bright (near) left half, dark (far) right half
    d = luminance_depth(rgb)
    assert d.dtype == np.float32 and d[20, 35] > d[20, 5]
    tissue = np.zeros((40, 40), bool)
    tissue[5:35, 5:35] = True
    pred = np.where(tissue, 1.0, 0.0)
    assert outside_share(pred, tissue) == 0.0
    pred[0, :] = 2.0
    assert outside_share(pred, tissue) == pytest.approx(40 / (~tissue).sum())
    assert outside_share(pred, np.ones((40, 40), bool)) is None


def _fake_split(folder, n: int = 6, size: tuple[int, int] = (64, 60)) -> None:
    """A split clip in split.py's layout: rgb/, depth_render/, occlusion/ (NNNNNN.png, 3-channel,
    as split.py writes them), camera.json; a round field of view on a black border."""
    w, h = size
    rng = np.random.default_rng(0)
    yy, xx = np.mgrid[:h, :w]
    inside = (xx - w / 2) ** 2 + (yy - h / 2) ** 2 < (0.45 * min(w, h)) ** 2
    for d in ("rgb", "depth_render", "occlusion"):
        (folder / d).mkdir(parents=True)
    for k in range(n):
        rgb = (rng.uniform(60, 250, (h, w, 3)) * inside[..., None]).astype(np.uint8)
        grey = (np.clip(xx * 3 + k, 1, 255) * inside).astype(np.uint8)
        occ = np.zeros((h, w), np.uint8)
        occ[:8, :] = 255
        cv2.imwrite(str(folder / "rgb" / f"{k:06d}.png"), rgb)
        cv2.imwrite(str(folder / "depth_render" / f"{k:06d}.png"), cv2.merge([grey] * 3))
        cv2.imwrite(str(folder / "occlusion" / f"{k:06d}.png"), cv2.merge([occ] * 3))
    cam = {"width": w, "height": h, "fx": 50.0, "fy": 50.0, "cx": (w - 1) / 2, "cy": (h - 1) / 2, "distortion": [],
           "depth_scale": 10000.0}
    (folder / "camera.json").write_text(json.dumps(cam))


def test_phantom_reader_on_a_fake_split_folder(tmp_path):
    from datamodules.phantom import read_phantom, split_folder

    _fake_split(tmp_path / "clip")
    assert split_folder(tmp_path / "clip", tmp_path / "work") == tmp_path / "clip"
    clip = read_phantom(tmp_path / "clip", every=4)
    assert clip.indices == [0, 4] and len(clip.rgb) == len(clip.depth) == len(clip.occluded) == 2
    assert clip.rgb[0].shape == (60, 64, 3) and clip.rgb[0].dtype == np.uint8
    assert clip.depth[0].dtype == np.float32 and clip.occluded[0].dtype == bool
    assert clip.camera.width == 64 and clip.camera.height == 60
    t = clip.tissue.pixels
    assert not t[0, 0] and t[30, 32] and 0.3 < clip.tissue.share < 0.8  # the black border is not tissue
    assert np.isnan(clip.depth[0][0, 0]) and clip.depth[1][30, 40] > clip.depth[1][30, 20]  # larger = farther
    valid = clip.valid(0)
    assert not valid[:8].any() and valid[30, 32] and not (valid & ~t).any()  # occluded rows and border left out


def test_phantom_reader_refuses_an_incomplete_folder(tmp_path):
    from datamodules.phantom import read_phantom, split_folder

    _fake_split(tmp_path / "clip", n=3)
    (tmp_path / "clip" / "occlusion" / "000001.png").unlink()
    with pytest.raises(InputError, match="000001.png"):
        read_phantom(tmp_path / "clip")
    with pytest.raises(InputError, match="--phantom"):
        split_folder(tmp_path / "nothing", tmp_path / "work")


def test_zoo_real_section_refuses_without_phantom(tmp_path, capsys):
    from benchmarks.protocols import zoo

    report = tmp_path / "zoo.md"
    with pytest.raises(SystemExit) as exc:
        zoo.main(["--set", "only=real", "--work", str(tmp_path / "work"), "--report", str(report)])
    assert exc.value.code == 2
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert len(err) == 1 and err[0].startswith("error: ") and "--phantom" in err[0]
    assert not report.exists() and not (tmp_path / "work").exists()


def test_zoo_real_section_lines():
    from benchmarks.protocols import zoo

    rho = {"per_frame": [0.9, 0.8], "pixels": [10, 10], "mean": 0.85, "median": 0.85, "pooled": 0.84}
    before = {"spearman": rho, "outside_network": 1.0, "outside_runtime": 0.0}
    after = {"spearman": {**rho, "mean": 0.9}, "outside_network": 1.0, "outside_runtime": 0.0}
    r = {"frames": [0, 24], "tissue_share": 0.9, "tissue_source": "detected", "counted_share": 0.8, "ttt_steps": 5,
         "darker_is_farther": {**rho, "mean": 0.7}, "models": {
             "a": {"before": before, "after": after, "guard": {"best_step": 3, "events": [{"event": "collapse"}]}},
             "b": {"before": before}}}
    text = "\n".join(zoo.real_lines(r))
    assert "| zoo:a | 0.850 (0.850; 0.840) | 0.900 (0.850; 0.840) | +0.050 |" in text and "3, collapse" in text
    assert "| zoo:b | 0.850 (0.850; 0.840) | not measured |" in text and "| darker is farther" in text
    assert "One frame in 24" in text and "5 steps" in text
