"""Keypoint descriptor files (``descriptor_sampling: keypoints``) in the runtime: the same
descriptors as the dense file sampled by the runtime's rule, the feed checks, the one-line
refusals, the choice of the export's keypoint file beside a dense one, and old dense files.

The models are the closed-form fixtures of tests/onnx_fixtures.py (no torch); the keypoint
variant samples the dense fixture's map with ONNX ``GridSample``.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from c3f_core.errors import InputError
from c3f_slam.camera.intrinsics import PinholeCamera
from c3f_slam.cli.main import main
from c3f_slam.matching import Keypoints, sample_descriptor_map
from c3f_slam.models import DescriptorModel, ModelMetadata, OnnxModel
from c3f_slam.models.zoo import sha256_of
from c3f_slam.pipeline.frontend import ContraFeatDescriptors
from tests import onnx_fixtures as fx

# An 80x72 frame, centre crop 64x64 at (8, 4), network 32x32 (as tests/test_slam_models.py).
CAM = PinholeCamera(80, 72, 60.0, 60.0, 39.5, 35.5)
CROP, SIZE = (64, 64), (32, 32)
TOL = 1e-5


def _one_line(exc: pytest.ExceptionInfo, *parts: str) -> str:
    msg = str(exc.value)
    assert "\n" not in msg and all(p in msg for p in parts), msg
    return msg


def _network_keypoints(rng: np.random.Generator, n: int, w: int, h: int) -> np.ndarray:
    """(n + 10, 2) float32 network pixels: corners, borders, outside the grid, sub-pixel positions."""
    fixed = [[0, 0], [w - 1, 0], [0, h - 1], [w - 1, h - 1], [w / 2 + 0.5, 0], [0, h / 3 + 0.25],
             [-3.0, h / 2], [w + 2.5, -1.5], [w / 2, h + 4.0], [10.125, 7.875]]
    return np.concatenate([fixed, rng.uniform(0, [w - 1, h - 1], (n, 2))]).astype(np.float32)


def _export_folder(folder: Path, size=SIZE, crop=CROP, dynamic=False, **kp_meta) -> tuple[Path, Path]:
    """A dense and a keypoint fixture file with the export.json an export writes beside them."""
    folder.mkdir(parents=True, exist_ok=True)
    dense = fx.descriptor_model(folder / "contrafeat.onnx", size, crop, dim=8, dynamic=dynamic)
    kp = fx.keypoint_descriptor_model(folder / "contrafeat_kp.onnx", size, crop, dim=8, dynamic=dynamic, **kp_meta)
    files = {p.name: {"kind": "descriptors", "descriptor_sampling": s, "sha256": sha256_of(p)}
             for p, s in ((dense, "dense"), (kp, "keypoints"))}
    (folder / "export.json").write_text(json.dumps({"files": files}))
    return dense, kp


def test_keypoint_graph_equals_the_dense_map_sampled_at_the_keypoints(tmp_path):
    """Batch of 2 at the metadata size and at another size (dynamic): every keypoint, borders
    and outside points included, within 1e-5 of sample_descriptor_map on the dense output."""
    dense_path, kp_path = _export_folder(tmp_path, dynamic=True)
    dense, kp = OnnxModel(dense_path), OnnxModel(kp_path)
    assert kp.input_names == ("image", "keypoints") and kp.metadata.sampling == "keypoints"
    assert dense.metadata.sampling == "dense"
    rng = np.random.default_rng(0)
    for h, w in ((32, 32), (24, 40)):
        images = rng.random((2, 3, h, w), dtype=np.float32)
        points = np.stack([_network_keypoints(rng, 30, w, h) for _ in range(2)])
        got = kp.run({"image": images, "keypoints": points})["descriptors"]
        maps = dense.run({"image": images})["descriptors"]
        want = np.stack([sample_descriptor_map(m, p) for m, p in zip(maps, points)])
        assert got.shape == (2, 40, 8) and got.dtype == np.float32
        np.testing.assert_allclose(got, want, rtol=0, atol=TOL)
        np.testing.assert_allclose(np.linalg.norm(got, axis=2), 1.0, atol=1e-6)
        assert np.abs(got[0] - got[1]).max() > 0.01  # each batch item sampled at its own keypoints


def test_contrafeat_descriptors_are_the_same_on_either_file(tmp_path):
    dense_path, kp_path = _export_folder(tmp_path)
    rng = np.random.default_rng(3)
    rgb = rng.integers(0, 200, (72, 80, 3), dtype=np.uint8)
    xy = np.concatenate([rng.uniform([8, 4], [71, 67], (60, 2)),  # inside the crop box, sub-pixel
                         [[8, 4], [71.0, 67.0], [2.0, 70.0], [79.0, 0.0], [40.25, 36.75]]])
    kps = Keypoints(xy=xy, size=np.ones(len(xy), np.float32), response=np.ones(len(xy), np.float32))
    a = ContraFeatDescriptors(DescriptorModel(dense_path), CAM).describe(rgb, kps)
    b = ContraFeatDescriptors(DescriptorModel(kp_path), CAM).describe(rgb, kps)
    assert a.shape == b.shape == (65, 8)
    np.testing.assert_allclose(b, a, rtol=0, atol=TOL)
    assert DescriptorModel(kp_path).describe(rgb, CAM, np.zeros((0, 2))).shape == (0, 8)


def test_a_keypoint_file_where_the_dense_map_is_needed_is_one_line(tmp_path):
    _, kp_path = _export_folder(tmp_path)
    model = DescriptorModel(kp_path, option="--feature-model")
    rgb = np.zeros((72, 80, 3), np.uint8)
    with pytest.raises(InputError) as exc:
        model.descriptor_map(rgb, CAM)
    _one_line(exc, "--feature-model: ", "contrafeat_kp.onnx", "is a keypoint descriptors model")
    with pytest.raises(InputError) as exc:
        model.describe_batch(np.zeros((1, 3, 32, 32), np.float32))
    _one_line(exc, "contrafeat_kp.onnx", "a dense descriptor map needs the dense file")


def test_malformed_keypoint_feeds_are_one_line(tmp_path):
    _, kp_path = _export_folder(tmp_path)
    model = OnnxModel(kp_path, option="--feature-model")
    image = np.zeros((1, 3, 32, 32), np.float32)
    cases = {
        "float64": (np.zeros((1, 5, 2)), "must be float32"),
        "list": ([[1.0, 2.0]], "must be a NumPy array"),
        "(N, 2)": (np.zeros((5, 2), np.float32), "must be (B, N, 2)"),
        "(B, N, 3)": (np.zeros((1, 5, 3), np.float32), "must be (B, N, 2)"),
        "other batch": (np.zeros((2, 5, 2), np.float32), "has a batch of 2, the images 1"),
        "no points": (np.zeros((1, 0, 2), np.float32), "holds no keypoints"),
        "nan": (np.array([[[1.0, np.nan]]], np.float32), "non-finite"),
    }
    for case, (bad, expected) in cases.items():
        with pytest.raises(InputError) as exc:
            model.run({"image": image, "keypoints": bad})
        assert _one_line(exc, "--feature-model: ", "contrafeat_kp.onnx", "'keypoints'", expected), case
    with pytest.raises(InputError, match="do not match the model inputs"):
        model.run({"image": image})


def test_keypoint_metadata_on_a_dense_graph_and_bad_sampling_values_are_refused(tmp_path):
    meta = fx.metadata("descriptors", SIZE, dim=8, descriptor_sampling="keypoints")
    fx.write(tmp_path / "wrong.onnx", fx.descriptor_graph(SIZE, 8), meta)
    with pytest.raises(InputError) as exc:
        OnnxModel(tmp_path / "wrong.onnx", option="--feature-model")
    _one_line(exc, "wrong.onnx", "graph has inputs ['image']", "'keypoints'")
    props = fx.metadata("descriptors", SIZE, dim=8).to_props()
    for value in ('"sparse"', '"keypoints"'):
        bad = dict(props, **{"c3f.descriptor_sampling": value})
        if value == '"keypoints"':  # on a depth model
            bad = dict(fx.metadata("depth", SIZE).to_props(), **{"c3f.descriptor_sampling": value})
        fx.write(tmp_path / "bad.onnx", fx.descriptor_graph(SIZE, 8), bad)
        with pytest.raises(InputError) as exc:
            OnnxModel(tmp_path / "bad.onnx", option="--feature-model")
        _one_line(exc, "--feature-model: ", "bad.onnx", "descriptor_sampling must be one of")


def test_old_dense_files_load_unchanged(tmp_path):
    """A file written before descriptor_sampling existed (no such key) is a dense model."""
    props = fx.metadata("descriptors", SIZE, CROP, dim=8).to_props()
    del props["c3f.descriptor_sampling"]
    old = fx.write(tmp_path / "old.onnx", fx.descriptor_graph(SIZE, 8), props)
    model = DescriptorModel(old, prefer_keypoints=True)
    assert model.metadata.descriptor_sampling is None and model.sampling == "dense"
    assert model.onnx.path == old and model.keypoint_file == "no export.json beside old.onnx"
    rgb = np.random.default_rng(1).integers(0, 200, (72, 80, 3), dtype=np.uint8)
    dmap, view = model.descriptor_map(rgb, CAM)
    xy = np.array([[10.0, 12.5], [40.25, 30.0]])
    np.testing.assert_array_equal(model.describe(rgb, CAM, xy), sample_descriptor_map(dmap, view.frame_to_network(xy)))
    assert ModelMetadata.from_props(props).describe().startswith("descriptors model")


def test_the_committed_zoo_features_load_as_dense():
    model = DescriptorModel("zoo:c3f-features-r18w32", option="--feature-model", prefer_keypoints=True)
    assert model.sampling == "dense" and model.onnx.path.name == "contrafeat.onnx"
    assert model.keypoint_file.startswith("not looked for: a zoo entry")
    rgb = np.random.default_rng(2).integers(0, 255, (128, 128, 3), dtype=np.uint8)
    cam = PinholeCamera(128, 128, 100.0, 100.0, 63.5, 63.5)
    desc = model.describe(rgb, cam, np.array([[5.0, 7.5], [64.0, 64.0], [127.0, 127.0]]))
    assert desc.shape == (3, model.descriptor_dim)
    np.testing.assert_allclose(np.linalg.norm(desc, axis=1), 1.0, atol=1e-5)


def test_the_keypoint_file_of_the_same_export_is_preferred(tmp_path):
    dense, kp = _export_folder(tmp_path / "export")
    model = DescriptorModel(dense, prefer_keypoints=True)
    assert (model.onnx.path, model.given, model.keypoint_file, model.sampling) == (kp, dense, "used", "keypoints")
    assert DescriptorModel(dense).onnx.path == dense  # only when asked
    assert DescriptorModel(kp, prefer_keypoints=True).keypoint_file == "given"


def _use_of(dense: Path) -> tuple[str, str]:
    model = DescriptorModel(dense, prefer_keypoints=True)
    return model.onnx.path.name, model.keypoint_file


def test_a_keypoint_file_of_another_export_is_not_used(tmp_path):
    other = {"file": "other.ckpt", "sha256": "1" * 64}
    dense, _ = _export_folder(tmp_path / "ckpt", checkpoint=other)
    assert _use_of(dense) == ("contrafeat.onnx", "contrafeat_kp.onnx: it records another checkpoint (SHA-256)")
    dense, kp = _export_folder(tmp_path / "changed")
    fx.keypoint_descriptor_model(kp, SIZE, CROP, dim=8, created="2030-01-01T00:00:00Z")  # replaced after the export
    assert _use_of(dense) == ("contrafeat.onnx", "contrafeat_kp.onnx does not match its SHA-256 in export.json")
    dense, kp = _export_folder(tmp_path / "unlisted")
    manifest = json.loads((tmp_path / "unlisted" / "export.json").read_text())
    del manifest["files"]["contrafeat_kp.onnx"]
    (tmp_path / "unlisted" / "export.json").write_text(json.dumps(manifest))
    assert _use_of(dense) == ("contrafeat.onnx", "export.json lists no keypoint descriptors file")
    dense, kp = _export_folder(tmp_path / "missing")
    kp.unlink()
    assert _use_of(dense) == ("contrafeat.onnx", "contrafeat_kp.onnx, listed in export.json, is missing")
    (tmp_path / "elsewhere").mkdir()
    moved = (tmp_path / "elsewhere" / "contrafeat.onnx")
    moved.write_bytes(dense.read_bytes())
    (tmp_path / "elsewhere" / "export.json").write_text(json.dumps({"files": {"depthnet.onnx": {"kind": "depth"}}}))
    assert _use_of(moved) == ("contrafeat.onnx", "export.json does not list contrafeat.onnx")
    dense, _ = _export_folder(tmp_path / "precision", precision="int8")
    assert _use_of(dense) == ("contrafeat.onnx",
                              "contrafeat_kp.onnx: its precision (int8) is not the dense file's (float32)")


def test_run_records_which_descriptor_file_was_used(tiny_sequence, tmp_path):
    dense, kp = _export_folder(tmp_path / "export", size=(32, 32), crop=(56, 56))
    out = tmp_path / "run"
    assert main(["run", str(tiny_sequence), "--feature-model", str(dense), "--depth-source", "files", "--out", str(out),
                 "--set", "fragments.min_correspondences=15", "--set", "fusion.enabled=false", "--quiet"]) == 0
    entry = json.loads((out / "summary.json").read_text())["models"]["descriptors"]
    assert entry["file"] == str(kp) and entry["given"] == str(dense)
    assert entry["descriptor_sampling"] == "keypoints" and entry["keypoint_file"] == "used"
    assert entry["model"].startswith("descriptors (at keypoints) model")


def test_inspect_says_how_a_descriptor_file_samples(tmp_path, capsys):
    parity = {"max_abs_diff": 1e-6, "tolerance": 1e-4, "frames": 2,
              "dense_sampling": {"max_abs_diff": 2e-7, "tolerance": 1e-5, "frames": 2, "keypoints": 64}}
    _, kp = _export_folder(tmp_path, parity=parity)
    assert main(["inspect", str(kp)]) == 0
    out = capsys.readouterr().out
    assert "descriptor dim:  8 (unit norm per keypoint; sampled at the given keypoints inside the graph)" in out
    assert "vs the dense graph sampled at the same keypoints: max |diff| 2e-07 (tolerance 1e-05, 64 keypoints)" in out
    assert "keypoints: (batch, keypoints, 2) float32" in out
    assert main(["inspect", str(tmp_path / "contrafeat.onnx")]) == 0
    assert "descriptor dim:  8 (unit norm per pixel)" in capsys.readouterr().out
