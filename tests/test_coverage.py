"""Unseen-surface estimate on analytic tubes: a straight tube seen all round, the
same tube with a band of angles no camera looks at, a fold that hides the wall behind it."""

from __future__ import annotations

import numpy as np
import pytest

from c3f_slam.camera.intrinsics import PinholeCamera
from c3f_slam.config import preset as slam_preset
from c3f_slam.coverage import CoverageConfig, ViewSettings, centreline_from_path, compute_coverage
from c3f_slam.geometry import transport_frames
from tests.scenes import tube_mesh, tube_views

CAM = PinholeCamera.from_fov(32, 32, 60.0)
VIEW = ViewSettings(width=CAM.width, height=CAM.height, depth_min=0.001, depth_max=0.2)
CFG = CoverageConfig()
S0, SIGMA = 0.05, 0.0025  # the fold: 5 cm along the tube, Gaussian width 2.5 mm


def _rows(cov, lo: float, hi: float) -> np.ndarray:
    s = cov.wall.s_centres
    return (s >= lo) & (s < hi)


def test_transport_frames_stay_orthonormal_without_twist():
    t = np.tile([0.0, 0.0, 1.0], (5, 1))
    n, b = transport_frames(t)
    assert np.allclose(n, [1.0, 0.0, 0.0]) and np.allclose(b, [0.0, 1.0, 0.0])
    a = np.linspace(0, np.pi / 2, 50)
    t = np.stack([np.cos(a), np.sin(a), np.zeros_like(a)], axis=1)  # a planar quarter circle
    n, b = transport_frames(t)
    assert np.allclose(np.einsum("ij,ij->i", b, t), 0, atol=1e-12)
    assert np.allclose(n, [0.0, 0.0, 1.0], atol=1e-9)  # the normal off the plane stays: no twist


def test_centreline_follows_forward_travel_only():
    """Back-and-forth and sideways motion add no length: 0 .. the farthest position."""
    z = np.concatenate([np.linspace(0, 0.08, 40), np.linspace(0.08, 0.03, 20), np.linspace(0.03, 0.1, 30)])
    wobble = 0.004 * np.sin(np.arange(len(z)))
    line = centreline_from_path(np.stack([wobble, 0 * z, z], axis=1), 0.005, 0.01, 0.002)
    assert line.length == pytest.approx(0.1, abs=0.004)
    assert np.all(np.diff(line.points[:, 2]) > 0)  # monotone along the tube
    assert centreline_from_path(np.zeros((10, 3)), 0.005, 0.01, 0.002) is None


def test_straight_tube_seen_all_round_is_fully_observed():
    poses = tube_views(np.arange(0, 0.1001, 0.004), np.arange(0, 360, 20))
    cov = compute_coverage(tube_mesh(), poses, CAM.K, VIEW, CFG)
    assert cov.length == pytest.approx(0.1, abs=0.002)
    assert cov.unseen_share() < 0.01
    assert cov.area.sum() == pytest.approx(2 * np.pi * 0.025 * cov.length, rel=0.01)
    assert all(seg["unseen_share"] < 0.01 for seg in cov.segments(0.05))


def test_band_never_in_view_is_its_share():
    """Views at 30..240 deg with a 60 deg field cover 0..270 deg: the 90 deg band left is
    25 % of the wall (tolerance 2 percentage points), the same in every segment."""
    poses = tube_views(np.arange(0, 0.1001, 0.004), np.arange(30, 241, 15))
    cov = compute_coverage(tube_mesh(), poses, CAM.K, VIEW, CFG)
    assert cov.unseen_share() == pytest.approx(0.25, abs=0.02)
    segs = cov.segments(0.025)
    assert len(segs) == 4 and all(seg["unseen_share"] == pytest.approx(0.25, abs=0.02) for seg in segs)
    theta, half = cov.wall.theta_centres, cov.wall.cell_angle / 2
    band = (theta > -np.pi / 2 + half) & (theta < 0)  # 270..360 deg, cells wholly inside
    outside = (theta > half) | (theta < -np.pi / 2 - half)
    assert (~cov.observed[:, band]).all() and cov.observed[:, outside].all()


def _forward(fold: bool, drop=None):
    cam = PinholeCamera.from_fov(48, 48, 110.0)
    view = ViewSettings(width=cam.width, height=cam.height, depth_min=0.001, depth_max=0.2)
    mesh = tube_mesh(fold=(S0, 0.4, SIGMA) if fold else None, drop=drop)
    return compute_coverage(mesh, tube_views(np.arange(0, 0.1001, 0.002)), cam.K, view, CFG)


@pytest.mark.parametrize("hole", [False, True], ids=["complete-surface", "hole-behind-fold"])
def test_fold_hides_the_wall_behind_it(hole):
    """Cameras on the axis looking forward: the back of the fold is unseen, the wall before it
    seen; without the fold the same band is seen. With the hidden wall missing from the
    surface (as fusion leaves it) the filled-in wall model still comes out unseen there."""
    drop = (lambda z, th: (z > S0 + SIGMA) & (z < S0 + 3 * SIGMA)) if hole else None
    cov = _forward(True, drop)
    behind, before = _rows(cov, S0 + 0.5 * SIGMA, S0 + 2 * SIGMA), _rows(cov, S0 - 0.03, S0 - 0.01)
    assert cov.unseen_share(behind) > 0.9
    assert cov.unseen_share(before) < 0.05
    if hole:
        assert not cov.wall.measured[_rows(cov, S0 + 1.2 * SIGMA, S0 + 2.8 * SIGMA)].any()
    plain = _forward(False)
    assert plain.unseen_share(_rows(plain, S0 + 0.5 * SIGMA, S0 + 2 * SIGMA)) < 0.05


# ---------------------------------------------------------------------- the run stage and evaluate

RUN = ["--set", "frames.max_frames=8", "--set", "fragments.min_correspondences=15", "--quiet"]


@pytest.fixture(scope="module")
def sim_sequence(tmp_path_factory):
    """128 px frames: enough correspondences to register and fuse a few frames."""
    from datamodules.synthetic.fixture import make_tiny_sequence

    return make_tiny_sequence(tmp_path_factory.mktemp("coverage") / "seq", frames=8, size=128, seed=3)


@pytest.fixture(scope="module")
def coverage_run(sim_sequence, tmp_path_factory):
    from c3f_slam.cli.main import main

    out = tmp_path_factory.mktemp("coverage_run") / "out"
    assert main(["run", str(sim_sequence), "--out", str(out), "--set", "coverage.segment=0.01", *RUN]) == 0
    return out


@pytest.mark.e2e
def test_run_writes_coverage_outputs(coverage_run):
    import json

    import cv2
    import open3d as o3d

    cov = json.loads((coverage_run / "coverage.json").read_text())
    assert cov["status"] == "ok" and 0 <= cov["unseen_share"] <= 1
    assert cov["observed_share"] == pytest.approx(1 - cov["unseen_share"])
    segs = cov["segments"]
    assert len(segs) == 3 and segs[0]["start_m"] == 0 and segs[1]["start_m"] == pytest.approx(0.01)
    assert segs[-1]["end_m"] == pytest.approx(cov["explored_length_m"])
    assert all(0 <= s["unseen_share"] <= 1 and s["start_m"] < s["end_m"] for s in segs)
    area = np.array([s["area_m2"] for s in segs])  # the overall share is the area-weighted mean
    assert cov["unseen_share"] == pytest.approx(float(area @ [s["unseen_share"] for s in segs] / area.sum()))
    assert cov["cells"]["observed"] + cov["cells"]["unseen"] == cov["cells"]["total"]
    summary = json.loads((coverage_run / "summary.json").read_text())
    assert summary["unseen_share"] == cov["unseen_share"] and summary["coverage"]["status"] == "ok"
    img = cv2.imread(str(coverage_run / "coverage_map.png"))
    assert img is not None and img.shape[0] > 100
    mesh = o3d.io.read_triangle_mesh(str(coverage_run / "mesh.ply"))
    painted = o3d.io.read_triangle_mesh(str(coverage_run / "unseen.ply"))
    # two triangles per unseen cell on top of the reconstruction
    assert len(painted.triangles) == len(mesh.triangles) + 2 * cov["cells"]["unseen"]


def test_no_coverage_and_bad_segment(sim_sequence, tmp_path, capsys):
    import json

    from c3f_slam.cli.main import main

    out = tmp_path / "off"
    assert main(["run", str(sim_sequence), "--out", str(out), "--set", "coverage.enabled=false", *RUN]) == 0
    assert not {"coverage.json", "coverage_map.png", "unseen.ply"} & {p.name for p in out.iterdir()}
    summary = json.loads((out / "summary.json").read_text())
    assert summary["coverage"]["status"] == "off" and "unseen_share" not in summary
    capsys.readouterr()
    # a bad setting: one error line, exit status 2, before the run folder
    assert main(["run", str(sim_sequence), "--out", str(tmp_path / "bad"), "--set", "coverage.segment=0", *RUN]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: --set: coverage.segment must be > 0")
    assert not (tmp_path / "bad").exists()


def test_no_mesh_says_why(sim_sequence, tmp_path):
    import json

    from c3f_slam.cli.main import main

    out = tmp_path / "nomesh"
    assert main(["run", str(sim_sequence), "--out", str(out), "--set", "fusion.enabled=false", *RUN]) == 0
    cov = json.loads((out / "coverage.json").read_text())
    assert cov["status"] == "unavailable" and "no mesh" in cov["reason"] and cov["unseen_share"] is None
    assert not (out / "coverage_map.png").exists()


def test_evaluate_reports_estimate_vs_truth(coverage_run, sim_sequence, capsys):
    import json

    from c3f_slam.cli.main import main

    capsys.readouterr()
    assert main(["evaluate", str(coverage_run), "--gt", str(sim_sequence)]) == 0
    printed = capsys.readouterr().out
    assert "unseen wall: estimate" in printed and "truth" in printed
    u = json.loads((coverage_run / "evaluation.json").read_text())["unseen"]
    cov = json.loads((coverage_run / "coverage.json").read_text())
    assert u["status"] == "ok" and u["estimate"] == cov["unseen_share"] and 0 <= u["truth"] <= 1
    assert u["error_pp"] == pytest.approx(100 * (u["estimate"] - u["truth"]))
    assert len(u["segments"]) == len(cov["segments"])
    assert u["explored_length_m"]["truth"] == pytest.approx(cov["explored_length_m"], abs=0.002)
    assert (coverage_run / u["truth_map"]).is_file()


def test_settings_are_checked_and_room_has_none():
    from c3f_core.errors import InputError

    with pytest.raises(InputError, match="coverage.segment"):
        slam_preset("colon", coverage={"segment": -1.0})
    assert slam_preset("colon").coverage.enabled
    assert not slam_preset("room").coverage.enabled
    assert CoverageConfig().depth_range(0.001, 0.2) == (0.001, 0.2)
    assert CoverageConfig(depth_max=0.05).depth_range(0.001, 0.2) == (0.001, 0.05)


@pytest.mark.parametrize("seen", [True, False])
def test_evaluate_reports_the_data_sets_own_flags(coverage_run, sim_sequence, tmp_path, capsys, seen):
    """mesh_observed.txt beside mesh.ply (converted C3VD): the data set's unseen share is reported
    beside the estimate and our truth, overall and on the same segments."""
    import json
    import shutil

    import open3d as o3d

    from c3f_slam.cli.main import main
    from c3f_slam.coverage.dataset_truth import FLAGS_FILE, write_observed_flags

    gt = shutil.copytree(sim_sequence, tmp_path / "gt")
    run = shutil.copytree(coverage_run, tmp_path / "run")
    n = len(o3d.io.read_triangle_mesh(str(gt / "mesh.ply")).triangles)
    write_observed_flags(gt / FLAGS_FILE, np.full(n, seen))
    capsys.readouterr()
    assert main(["evaluate", str(run), "--gt", str(gt)]) == 0
    assert "the data set's own flags" in capsys.readouterr().out
    u = json.loads((run / "evaluation.json").read_text())["unseen"]
    assert u["dataset"] == (0.0 if seen else 1.0) and u["dataset_file"] == FLAGS_FILE
    assert all(s["dataset"] == u["dataset"] for s in u["segments"])


def test_malformed_dataset_flags_are_one_line_errors(coverage_run, sim_sequence, tmp_path, capsys):
    import shutil

    from c3f_slam.cli.main import main
    from c3f_slam.coverage.dataset_truth import FLAGS_FILE

    gt = shutil.copytree(sim_sequence, tmp_path / "gt")
    for text, message in (("1\n0\n", "observed flags for a mesh of"), ("1\n2\n", ":2: observed flag must be 0 or 1")):
        (gt / FLAGS_FILE).write_text(text)
        capsys.readouterr()
        assert main(["evaluate", str(coverage_run), "--gt", str(gt)]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith("error: ") and FLAGS_FILE in err[0] and message in err[0]
