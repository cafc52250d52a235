"""``python -m datamodules convert``: published layouts into the project's, whole or nothing."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.testing import assert_allclose

from c3f_slam import geometry as g
from c3f_slam.io import Sequence
from datamodules.__main__ import main
from datamodules.convert import convert
from tests.published_data import FRAMES, SEQUENCE_DIR, copy_layout

NAMES = {"uts": "Case0001", "simcol3d": "SyntheticColon_C3F_Frames_S1", "c3vd": "c3f_sim", "colon10k": "c3f_sim"}


@pytest.mark.parametrize("layout", ["uts", "simcol3d", "c3vd", "colon10k"])
def test_convert_reproduces_the_simulators_sequence(published, tmp_path, layout):
    sim, root = published(layout)
    done = convert(layout, root, tmp_path / "out", progress=False, report=lambda line: None)
    assert [d.name for d in done] == [NAMES[layout]]
    out = Sequence(tmp_path / "out" / NAMES[layout])
    ref = Sequence(sim)
    assert len(out) == FRAMES
    for k in ("width", "height", "fx", "fy", "cx", "cy"):
        assert getattr(out.camera, k) == pytest.approx(getattr(ref.camera, k), rel=1e-6)
    if layout == "colon10k":
        assert not out.has_depth and not out.has_poses
        return
    rgb_tol = 0 if layout in ("uts", "simcol3d") else 255
    depth_tol = 1e-4 if layout in ("uts", "simcol3d") else None
    for i in range(FRAMES):
        assert np.abs(out.read_rgb(i).astype(int) - ref.read_rgb(i)).max() <= rgb_tol
        if depth_tol is not None:
            assert_allclose(out.read_depth(i), ref.read_depth(i), atol=depth_tol)
        expected = g.relative_pose(ref.pose(0), ref.pose(i)) if layout == "uts" else ref.pose(i)
        assert_allclose(out.pose(i), expected, atol=1e-6)
    assert (out.mesh_path is not None) == (layout == "c3vd")


def test_convert_is_lossless_for_the_native_depth(published, tmp_path):
    """Converted depth keeps the raw values: depth_scale is the data set's own resolution."""
    import cv2

    _, root = published("simcol3d")
    convert("simcol3d", root, tmp_path / "out", progress=False, report=lambda line: None)
    raw = cv2.imread(str(root / SEQUENCE_DIR["simcol3d"] / "Depth_0002.png"), cv2.IMREAD_UNCHANGED)
    out = cv2.imread(str(tmp_path / "out" / NAMES["simcol3d"] / "depth" / "000002.png"), cv2.IMREAD_UNCHANGED)
    assert (out == np.where(raw == 65535, 0, raw)).all()  # the same values; only the saturated ones become 0


def test_cli_refuses_to_overwrite_and_leaves_nothing_half_written(published, tmp_path, capsys):
    _, root = published("simcol3d")
    dst = tmp_path / "dst"
    assert main(["convert", "simcol3d", str(root), "--out", str(dst), "--no-progress"]) == 0
    assert "SyntheticColon_C3F_Frames_S1: 5 frames, depth, poses ->" in capsys.readouterr().out
    assert main(["convert", "simcol3d", str(root), "--out", str(dst), "--no-progress"]) == 2
    assert "exists and is not empty (use --overwrite" in capsys.readouterr().err
    broken = copy_layout(root, tmp_path / "broken")
    (broken / SEQUENCE_DIR["simcol3d"] / "FrameBuffer_0004.png").write_bytes(b"not a png")
    before = sorted(p.relative_to(dst) for p in dst.rglob("*"))
    assert main(["convert", "simcol3d", str(broken), "--out", str(dst), "--overwrite", "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "FrameBuffer_0004.png: image does not decode" in err[0] and "not written" in err[0]
    assert sorted(p.relative_to(dst) for p in dst.rglob("*")) == before  # the earlier sequence is intact
    assert not [p for p in dst.iterdir() if p.name.startswith(".")]  # no partial folder left


def test_cli_bad_input_one_line(published, tmp_path, capsys):
    _, root = published("uts")
    assert main(["convert", "simcol3d", str(root), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "no SimCol3D sequences found" in err and "looks like UTS-synthetic" in err
    assert main(["list", "uts", str(root), "--calibration", "x"]) == 2
    assert "--calibration: not an option of uts" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_cli_list(published, capsys):
    _, root = published("c3vd")
    assert main(["list", "c3vd", str(root)]) == 0
    assert "c3f_sim: 5 frames 135x108, fx 76.92" in capsys.readouterr().out


def test_slam_and_evaluate_run_on_a_converted_sequence(published, tmp_path):
    from c3f_slam.cli.main import main as slam

    _, root = published("simcol3d")
    convert("simcol3d", root, tmp_path / "conv", progress=False, report=lambda line: None)
    seq = tmp_path / "conv" / NAMES["simcol3d"]
    out = tmp_path / "run"
    assert slam(["run", str(seq), "--depth-source", "files", "--descriptors", "sift", "--out", str(out),
                 "--quiet"]) == 0
    assert (out / "trajectory.txt").is_file()
    assert slam(["evaluate", str(out), "--gt", str(seq)]) == 0
    assert (out / "evaluation.json").is_file()


def test_convert_keeps_c3vds_observed_flags(published, tmp_path):
    """coverage_mesh.obj's per-face flags (vt 1 = observed, 2 = never) survive as mesh_observed.txt,
    one line per triangle of mesh.ply in its order."""
    import open3d as o3d

    from c3f_slam.coverage.dataset_truth import FLAGS_FILE, read_observed_flags
    from datamodules.formats.c3vd import read_obj

    _, root = published("c3vd")
    convert("c3vd", root, tmp_path / "out", progress=False, report=lambda line: None)
    seq = tmp_path / "out" / "c3f_sim"
    mesh = o3d.io.read_triangle_mesh(str(seq / "mesh.ply"))
    flags = read_observed_flags(seq / FLAGS_FILE, len(mesh.triangles))
    V, F, expected = read_obj(root / SEQUENCE_DIR["c3vd"] / "coverage_mesh.obj")
    assert (flags == expected).all() and flags.any() and not flags.all()  # 5 frames see part of the colon
    assert (np.asarray(mesh.triangles) == F).all()


@pytest.mark.parametrize(("face", "message"), [("f 1/3 2/3 3/3", "coverage texture coordinate 3"),
                                               ("f 1 2 3", "have no coverage texture coordinate"),
                                               ("f 1/x 2/1 3/1", "non-integer index")])
def test_malformed_c3vd_flags_are_one_line_errors(published, tmp_path, face, message, capsys):
    _, root = published("c3vd")
    broken = copy_layout(root, tmp_path / "broken")
    obj = broken / SEQUENCE_DIR["c3vd"] / "coverage_mesh.obj"
    obj.write_text(obj.read_text() + face + "\n")
    assert main(["convert", "c3vd", str(broken), "--out", str(tmp_path / "out"), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: ") and "coverage_mesh.obj" in err[0] and message in err[0]
    assert not (tmp_path / "out" / "c3f_sim").exists()
