"""The SimCol3D challenge's metrics and submission files (c3f_slam.io.simcol3d) and the
``python -m c3f_slam simcol3d`` command."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from c3f_core.errors import InputError
from c3f_slam.cli.main import main
from c3f_slam.geometry import axis_angle_to_matrix, make_pose
from c3f_slam.io import Sequence
from c3f_slam.io import simcol3d as sc
from c3f_slam.io.tum import write_tum
from datamodules.formats import simcol3d as simcol_format
from tests import onnx_fixtures as fx
from tests.published_data import SEQUENCE_DIR


def _random_poses(n: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.asarray([make_pose(axis_angle_to_matrix(rng.normal(scale=0.5, size=3)), rng.normal(scale=0.05, size=3))
                       for _ in range(n)])


# ---------------------------------------------------------------------- depth metrics


def test_depth_prediction_up_to_scale_has_no_error():
    rng = np.random.default_rng(0)
    gts = [rng.uniform(0.02, 0.18, (12, 10)) for _ in range(3)]
    r = sc.depth_metrics_per_trajectory([0.5 * g for g in gts], gts)
    assert r["scale"] == pytest.approx(2.0)
    assert r["l1_cm"] == pytest.approx(0, abs=1e-9) and r["rmse_cm"] == pytest.approx(0, abs=1e-9)
    assert r["median_rel_pct"] == pytest.approx(0, abs=1e-9) and r["frames"] == 3


def test_depth_known_offset():
    """+-1 cm on halves of a 10 cm wall: the means agree (scale 1), L1 = RMSE = 1 cm, relative 1 / 10 cm."""
    gt = np.full((4, 6), 0.10)
    pred = gt + np.where(np.arange(6) < 3, 0.01, -0.01)
    r = sc.depth_metrics_per_trajectory([pred, pred], [gt, gt])
    assert r["scale"] == pytest.approx(1.0)
    assert r["l1_cm"] == pytest.approx(1.0) and r["rmse_cm"] == pytest.approx(1.0)
    assert r["median_rel_pct"] == pytest.approx(100 / (10 + 1e-4))


def test_depth_scale_on_frame_means_and_clipping():
    """One scale from the per-frame means (not per pixel), predictions clipped to [0, 20 cm]
    (NaN: 0) before it; the per-frame errors are averaged over frames."""
    rng = np.random.default_rng(1)
    gts = [rng.uniform(0.01, 0.2, (8, 8)) for _ in range(4)]
    preds = [g * rng.uniform(0.5, 1.5, g.shape) for g in gts]
    preds[0][0, :3] = (0.5, np.nan, -1.0)
    r = sc.depth_metrics_per_trajectory(preds, gts)
    p = [np.clip(np.nan_to_num(x / 0.2), 0, 1) for x in preds]
    g = [x / 0.2 for x in gts]
    mp, mg = np.array([x.mean() for x in p]), np.array([x.mean() for x in g])
    s = (mp * mg).sum() / (mp * mp).sum()
    d = [20 * s * a - 20 * b for a, b in zip(p, g)]
    assert r["scale"] == pytest.approx(s)
    assert r["l1_cm"] == pytest.approx(np.mean([np.abs(x).mean() for x in d]))
    assert r["rmse_cm"] == pytest.approx(np.mean([np.sqrt((x * x).mean()) for x in d]))
    assert r["median_rel_pct"] == pytest.approx(
        np.mean([100 * np.median(np.abs(x) / (20 * b + 1e-4)) for x, b in zip(d, g)]))


def test_depth_metrics_bad_input():
    with pytest.raises(InputError, match=r"preds\[0\]: shape"):
        sc.depth_metrics_per_trajectory([np.ones((2, 3))], [np.ones((3, 2))])
    with pytest.raises(InputError, match="1 depth maps for 2"):
        sc.depth_metrics_per_trajectory([np.ones((2, 2))], [np.ones((2, 2))] * 2)
    with pytest.raises(InputError, match="no scale"):
        sc.depth_metrics_per_trajectory([np.zeros((2, 2))], [np.ones((2, 2))])


def test_mean_over_trajectories():
    m = sc.mean_over_trajectories([{"l1_cm": 1.0, "rmse_cm": 2.0, "frames": 3},
                                   {"l1_cm": 3.0, "rmse_cm": 4.0, "frames": 5}])
    assert m == {"l1_cm": 2.0, "rmse_cm": 3.0, "frames": 8, "trajectories": 2}


# ---------------------------------------------------------------------- depth files


def test_depth_file_format_and_round_trip(tmp_path):
    rng = np.random.default_rng(2)
    depth = rng.uniform(0.0, 0.2, (475, 475)).astype(np.float32)
    depth[0, :4] = (np.nan, np.inf, 0.3, -0.1)
    path = sc.write_depth_prediction(tmp_path / "FrameBuffer_0007", depth)
    assert path.name == "FrameBuffer_0007.npy"
    raw = np.load(path)
    assert raw.dtype == np.float16 and raw.shape == (475, 475) and raw.min() >= 0 and raw.max() <= 1
    assert raw[0, :4].tolist() == [0.0, 1.0, 1.0, 0.0]
    back = sc.read_depth_prediction(path)
    assert np.abs(back[1:] - depth[1:]).max() < 0.2 * 2**-11  # float16 step below 1


def test_depth_file_resized(tmp_path):
    """Another size is resized (bilinear) to 475 x 475: a plane stays a plane."""
    depth = np.tile(np.linspace(0.02, 0.12, 64, dtype=np.float32), (48, 1))
    out = sc.read_depth_prediction(sc.write_depth_prediction(tmp_path / "d.npy", depth))
    assert out.shape == (475, 475)
    assert np.allclose(out[:, 5], out[0, 5]) and out[0, 0] < out[0, 237] < out[0, -1]
    assert out[0, 237] == pytest.approx(0.07, abs=1e-3)


def test_depth_reader_refuses_other_formats(tmp_path):
    np.save(tmp_path / "f32.npy", np.zeros((475, 475), np.float32))
    np.save(tmp_path / "small.npy", np.zeros((10, 10), np.float16))
    for name in ("f32.npy", "small.npy"):
        with pytest.raises(InputError, match=name):
            sc.read_depth_prediction(tmp_path / name)
    with pytest.raises(InputError, match="expected an"):
        sc.submission_depth(np.zeros(5))


def test_depth_writer_inverts_the_loader():
    """Depth as the project's SimCol3D loader reads a PNG value, written back, is the value the
    official script reads from that PNG (value / 255 / 256), to float16 precision."""
    raw = np.random.default_rng(3).integers(0, simcol_format.DEPTH_FULL_SCALE + 1, (475, 475))
    ours = raw * (simcol_format.DEPTH_RANGE_M / simcol_format.DEPTH_FULL_SCALE)
    official = raw / 255 / 256
    assert np.abs(sc.submission_depth(ours).astype(np.float64) - official).max() <= 2**-12


def test_gt_depth_png_as_the_official_script(published):
    _, root = published("simcol3d")
    frames = root / SEQUENCE_DIR["simcol3d"]
    seq = simcol_format.SimCol3DFormat().open(frames)
    raw = cv2.imread(str(frames / "Depth_0000.png"), cv2.IMREAD_UNCHANGED)
    gt = sc.read_gt_depth_png(frames / "Depth_0000.png")
    assert np.allclose(gt, raw / 255 / 256 * 0.2)
    ok = raw != simcol_format.SATURATED
    assert np.allclose(gt[ok], seq.read_depth(0)[ok], atol=1e-7)


# ---------------------------------------------------------------------- poses


def test_pose_metrics_perfect_up_to_scale():
    gt = _random_poses(6)
    pred = gt.copy()
    pred[:, :3, 3] *= 0.3
    r = sc.pose_metrics_per_trajectory(pred, gt)
    assert r["scale"] == pytest.approx(1 / 0.3) and r["pairs"] == 5
    assert r["ate_cm"] == pytest.approx(0, abs=1e-9) and r["rte_cm"] == pytest.approx(0, abs=1e-9)
    assert r["rot_deg"] == pytest.approx(0, abs=1e-5)


def test_pose_metrics_known_rotation_error():
    """Every predicted step turned 2 degrees more about z (same translations): scale 1, RTE 0, ROT 2."""
    gt_rel = sc.relative_poses(_random_poses(5, seed=4))
    extra = make_pose(axis_angle_to_matrix([0, 0, math.radians(2)]), np.zeros(3))
    r = sc.pose_metrics_from_relative(gt_rel @ extra, gt_rel)
    assert r["scale"] == pytest.approx(1.0)
    assert r["rte_cm"] == pytest.approx(0, abs=1e-9) and r["rot_deg"] == pytest.approx(2.0)


def test_pose_metrics_known_ate():
    """gt: 1 cm steps along z; pred turns 90 degrees about y first: positions 0, z, z+x, z+2x, z+3x
    (cm), errors 0, 0, sqrt 2, 2 sqrt 2, 3 sqrt 2; the median is sqrt 2 cm; relative errors 0 / 0."""
    step = make_pose(np.eye(3), [0, 0, 0.01])
    gt_rel = np.stack([step] * 4)
    pred_rel = gt_rel.copy()
    pred_rel[0, :3, :3] = axis_angle_to_matrix([0, math.pi / 2, 0])
    r = sc.pose_metrics_from_relative(pred_rel, gt_rel)
    assert r["scale"] == pytest.approx(1.0) and r["ate_cm"] == pytest.approx(math.sqrt(2))
    assert r["rte_cm"] == pytest.approx(0, abs=1e-9) and r["rot_deg"] == pytest.approx(0, abs=1e-6)


def test_pose_metrics_bad_input():
    with pytest.raises(InputError, match="pred: 2 relative poses for 3"):
        sc.pose_metrics_from_relative(sc.relative_poses(_random_poses(3)), sc.relative_poses(_random_poses(4)))
    with pytest.raises(InputError, match="poses: expected at least 2"):
        sc.relative_poses(np.eye(4)[None])


def test_pose_files_round_trip(tmp_path):
    poses = _random_poses(5, seed=5)
    files = sc.write_relative_poses(tmp_path / "pose", poses, numbers=[10, 11, 12, 13, 14])
    assert [f.name for f in files][:2] == ["FrameBuffer_0010_to_FrameBuffer_0011.txt",
                                          "FrameBuffer_0011_to_FrameBuffer_0012.txt"]
    lines = files[0].read_text().splitlines()
    vals = np.array(lines[0].split(), dtype=float)
    assert len(lines) == 1 and vals.shape == (16,) and lines[0].split()[12:] == ["0.0", "0.0", "0.0", "1.0"]
    rel = sc.relative_poses(poses)
    assert np.allclose(vals.reshape(4, 4)[:3, 3], 100 * rel[0, :3, 3])  # centimetres
    pairs, back = sc.read_relative_poses(tmp_path / "pose")
    assert pairs == [(10, 11), (11, 12), (12, 13), (13, 14)]
    assert np.allclose(back, rel, atol=1e-12)
    chained = sc.chain_relative_poses(back)
    assert np.allclose(chained, np.linalg.inv(poses[0]) @ poses, atol=1e-12)


def test_pose_file_errors(tmp_path):
    (tmp_path / "FrameBuffer_0000_to_FrameBuffer_0001.txt").write_text("1 2 3\n")
    with pytest.raises(InputError, match="FrameBuffer_0000_to_FrameBuffer_0001.txt: expected 16"):
        sc.read_relative_poses(tmp_path)
    with pytest.raises(InputError, match="pose folder not found"):
        sc.read_relative_poses(tmp_path / "nope")
    (tmp_path / "empty").mkdir()
    with pytest.raises(InputError, match="no FrameBuffer"):
        sc.read_relative_poses(tmp_path / "empty")


def _official_relative_gt(scene_dir, code: str) -> np.ndarray:
    """The ground-truth relative poses as eval_synthetic_pose.py builds them (cm)."""
    pos = np.loadtxt(scene_dir / f"SavedPosition_{code}.txt", ndmin=2)
    quat = np.loadtxt(scene_dir / f"SavedRotationQuaternion_{code}.txt", ndmin=2)
    TM = np.diag([1.0, -1.0, 1.0, 1.0])
    P = [TM @ make_pose(Rotation.from_quat(q).as_matrix(), t) @ TM for t, q in zip(pos, quat)]
    return np.asarray([np.linalg.inv(a) @ b for a, b in zip(P[:-1], P[1:])])


def test_pose_writer_inverts_the_loader(published, tmp_path):
    """A SimCol3D trajectory read by the project's loader and written back gives the relative
    poses the official script computes from SavedPosition / SavedRotationQuaternion."""
    _, root = published("simcol3d")
    frames = root / SEQUENCE_DIR["simcol3d"]
    seq = simcol_format.SimCol3DFormat().open(frames)
    files = sc.write_relative_poses(tmp_path, seq.poses)
    written = np.asarray([np.array(f.read_text().split(), dtype=float).reshape(4, 4) for f in files])
    official = _official_relative_gt(frames.parent, "S1")
    assert len(written) == len(official) == len(seq) - 1
    assert np.allclose(written, official, atol=1e-9)


# ---------------------------------------------------------------------- the command


def test_cli_writes_a_submission(tiny_sequence, tmp_path, capsys):
    seq = Sequence(tiny_sequence)
    model = fx.depth_model(tmp_path / "d.onnx", (32, 32))
    keep = [i for i in range(len(seq)) if i != 3]  # a frame the run did not register
    write_tum(tmp_path / "trajectory.txt", seq.timestamps[keep], seq.poses[keep])
    out = tmp_path / "sub" / "Frames_S1_OP"
    assert main(["simcol3d", str(tiny_sequence), "--depth-model", str(model), "--out", str(out),
                 "--trajectory", str(tmp_path / "trajectory.txt"), "--quiet"]) == 0
    assert "1 frame(s) without a pose interpolated" in capsys.readouterr().out
    depth_files = sorted((out / "depth").iterdir())
    assert [f.name for f in depth_files] == [f"FrameBuffer_{i:04d}.npy" for i in range(len(seq))]
    d = np.load(depth_files[0])
    assert d.dtype == np.float16 and d.shape == (475, 475)
    lo, hi = fx.DEPTH_A / 0.2, (fx.DEPTH_A + fx.DEPTH_B) / 0.2
    assert lo - 1e-3 <= d.min() and d.max() <= hi + 1e-3 and d.std() > 0
    pairs, rel = sc.read_relative_poses(out / "pose")
    assert pairs == [(i, i + 1) for i in range(len(seq) - 1)]
    chained = sc.chain_relative_poses(rel)
    truth = np.linalg.inv(seq.poses[0]) @ seq.poses
    assert np.allclose(chained[keep], truth[keep], atol=1e-6)
    assert sc.pose_metrics_from_relative(rel, sc.relative_poses(seq.poses))["rot_deg"] == pytest.approx(0, abs=1e-4)

    meta = fx.metadata("depth", (32, 32), depth={"min_depth": 0.01, "max_depth": 0.06, "metric_scale": 2.0})
    scaled = fx.write(tmp_path / "scaled.onnx", fx.depth_graph((32, 32)), meta)
    assert main(["simcol3d", str(tiny_sequence), "--depth-model", str(scaled), "--out", str(tmp_path / "s"),
                 "--quiet"]) == 0
    assert "(x2)" in capsys.readouterr().out and not (tmp_path / "s" / "pose").exists()
    d2 = np.load(tmp_path / "s" / "depth" / "FrameBuffer_0000.npy").astype(np.float64)
    assert np.allclose(d2, np.minimum(2 * d.astype(np.float64), 1.0), atol=2e-3)


def test_cli_errors(tiny_sequence, tmp_path, capsys):
    def one_error(argv):
        assert main(["simcol3d", str(tiny_sequence), "--out", str(tmp_path / "o"), *argv]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith("error: ")
        return err[0]

    assert "nothing to write" in one_error([])
    assert "trajectory file not found" in one_error(["--trajectory", str(tmp_path / "nope.txt")])
    far = tmp_path / "far.txt"
    write_tum(far, np.array([1000.0]), np.eye(4)[None])
    assert "no pose has the timestamp" in one_error(["--trajectory", str(far)])
