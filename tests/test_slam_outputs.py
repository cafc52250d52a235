"""Run outputs: TUM trajectory, summary JSON, keyframe graph JSON + PNG, all atomic."""

from __future__ import annotations

import json

import numpy as np
import pytest

from c3f_slam import geometry as g
from c3f_slam.io import read_tum
from c3f_slam.io.run_outputs import KeyframeGraph, RunOutputs, to_jsonable, write_trajectory
from c3f_slam.posegraph import PoseGraph

PNG = b"\x89PNG\r\n\x1a\n"


def _poses(n: int) -> np.ndarray:
    return np.array([g.make_pose(g.axis_angle_to_matrix([0.0, 0.1 * k, 0.0]), [0.01 * k, 0.0, 0.005 * k])
                     for k in range(n)])


def test_trajectory_only_registered(tmp_path):
    poses = _poses(5)
    poses[3] = np.nan  # an unregistered frame may also be marked by NaN
    registered = np.array([True, False, True, True, True])
    n = write_trajectory(tmp_path / "t.txt", np.arange(5) * 0.1, poses, registered)
    assert n == 3
    stamps, back = read_tum(tmp_path / "t.txt")
    assert stamps.tolist() == pytest.approx([0.0, 0.2, 0.4])
    np.testing.assert_allclose(back, poses[[0, 2, 4]], atol=1e-8)
    with pytest.raises(ValueError):
        write_trajectory(tmp_path / "t.txt", np.arange(4), poses)


def test_to_jsonable():
    data = {"a": np.float32(1.5), "b": np.arange(3), "c": float("nan"), "d": np.bool_(True), 3: [np.int64(2)]}
    assert to_jsonable(data) == {"a": 1.5, "b": [0, 1, 2], "c": None, "d": True, "3": [2]}


def test_run_outputs_all_files(tmp_path):
    out = RunOutputs(tmp_path / "run")
    poses = _poses(4)
    assert out.write_trajectory(np.arange(4.0), poses) == 4
    out.write_summary({"frames": np.int64(4), "ate_rmse_m": np.float64(0.012), "missing": float("inf")})
    summary = json.loads(out.summary.read_text())
    assert summary == {"frames": 4, "ate_rmse_m": 0.012, "missing": None}

    pg = PoseGraph()
    for P in poses:
        pg.add_node(P)
    rng = np.random.default_rng(0)
    pts = rng.uniform(-0.02, 0.02, size=(30, 3)) + [0, 0, 0.04]
    for k in range(3):
        pg.add_edge(k, k + 1, g.relative_pose(poses[k], poses[k + 1]), points_j=pts)
    wrong = g.relative_pose(poses[0], poses[2]) @ g.make_pose(np.eye(3), [0.05, 0.0, 0.0])
    pg.add_edge(0, 2, wrong, points_j=pts, uncertain=True)
    pg.optimize()
    graph = KeyframeGraph.from_posegraph(pg, frames=[0, 10, 20, 30], lone={3}, fragments=[0, 1, 2, 3])
    out.write_graph(graph)

    data = json.loads(out.graph_json.read_text())
    assert [n["frame"] for n in data["nodes"]] == [0, 10, 20, 30]
    assert [n["lone"] for n in data["nodes"]] == [False, False, False, True]
    assert data["nodes"][1]["position"] == pytest.approx(poses[1][:3, 3].tolist(), abs=1e-6)
    assert [e["kind"] for e in data["edges"]] == ["odometry"] * 3 + ["loop"]
    assert [e["pruned"] for e in data["edges"]] == [False, False, False, True]
    assert data["edges"][0]["n_matches"] == 30 and data["edges"][3]["rms_m"] > 0.01
    assert out.graph_png.read_bytes()[:8] == PNG and out.graph_png.stat().st_size > 1000

    names = sorted(p.name for p in out.root.iterdir())
    assert names == ["keyframe_graph.json", "keyframe_graph.png", "summary.json", "trajectory.txt"]  # no temp files

    with pytest.raises(ValueError):
        KeyframeGraph.from_posegraph(pg, frames=[0, 1])


def test_failed_write_keeps_previous_file(tmp_path):
    out = RunOutputs(tmp_path)
    out.write_summary({"ok": 1})
    with pytest.raises(TypeError):
        out.write_summary({"bad": object()})  # not serialisable
    assert json.loads(out.summary.read_text()) == {"ok": 1}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["summary.json"]
