"""The unseen wall kept up to date frame by frame, and the alert of the live view.

A straight tube (radius 2 cm) rendered by ray casting gives exact depth and poses: a camera
that looks along the tube sees all of its wall; one that turns to the +x wall over 10-15 cm
never sees that segment's -x half. The incremental estimate must tell them apart, the alert
must fire for the second withdrawal only and say where the gap is, and a frame's cost must
not depend on the length mapped before it.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from c3f_slam import geometry as g
from c3f_slam.config import CoverageConfig
from c3f_slam.coverage.incremental import GrowingCentreline, IncrementalWall, clock_position
from c3f_slam.live.alerts import SegmentWatch
from c3f_slam.view.raycast import MeshScene, render_pinhole
from tests.scenes import tube_mesh

W = H = 64
K = np.array([[W / 2, 0, (W - 1) / 2], [0, H / 2, (H - 1) / 2], [0, 0, 1.0]])  # 90 degrees across
NEAR_FAR = (0.001, 0.035)  # a short range: the wall of a segment is seen only from near it


@pytest.fixture(scope="module")
def tube() -> MeshScene:
    return MeshScene.of(tube_mesh(length=0.3, radius=0.02, margin=0.05, ds=0.001, n_theta=120))


def _poses(z: np.ndarray, turned: tuple[float, float] | None) -> np.ndarray:
    """Cameras on the axis at heights ``z``: looking along +z, or, between the heights of
    ``turned``, at the +x wall (75 degrees off the axis)."""
    out = []
    for zc in z:
        eye = np.array([0.0, 0.0, zc])
        look = np.array([0.0, 0.0, 1.0])
        if turned is not None and turned[0] <= zc <= turned[1]:
            a = math.radians(75)
            look = np.array([math.sin(a), 0.0, math.cos(a)])
        out.append(g.look_at(eye, eye + look, [0.0, -1.0, 0.0]))
    return np.stack(out)


def _withdrawal(tube: MeshScene, turned, cfg: CoverageConfig, threshold: float = 0.2):
    wall = IncrementalWall(cfg, K, NEAR_FAR)
    watch = SegmentWatch(cfg.segment, threshold, margin=0.01)
    alerts = []
    for i, T in enumerate(_poses(np.arange(0.0, 0.26, 0.002), turned)):
        _, depth = render_pinhole(tube, K, T, W, H)
        up = wall.add_frame(T, depth)
        alerts += watch.update(up.s, wall, T, i, float(i))
    wall.finish()
    alerts += watch.update(None, wall, T, i, float(i))
    return wall, alerts


def test_centreline_rows_follow_the_path_and_never_move():
    cfg = CoverageConfig()
    line = GrowingCentreline(cfg)
    made = 0
    snapshot = None
    for z in np.arange(0.0, 0.1, 0.001):
        made += line.push(np.array([0.001 * math.sin(40 * z), 0.0, z]))  # a wobbling path along +z
        if snapshot is None and line.n_rows >= 5:
            snapshot = line.centre.view[:5].copy()
    assert made == line.n_rows > 0
    np.testing.assert_array_equal(line.centre.view[:5], snapshot)  # rows stay where they were made
    # rows lag the camera by the smoothing window (2 sigma), and reach the end once finished
    assert 0.1 - 0.03 < line.rows_end < 0.1 - 0.01
    line.finish()
    assert line.rows_end > 0.095
    T = line.T.view
    assert np.all(T[:, 2] > 0.99)  # tangents along the tube
    N, B = line.N.view, line.B.view
    np.testing.assert_allclose(np.einsum("ij,ij->i", N, T), 0, atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(B, axis=1), 1, atol=1e-9)


def test_a_camera_that_looks_along_the_tube_sees_its_wall(tube):
    cfg = CoverageConfig(segment=0.05, live_min_points=1)  # exact depth: one point in a cell is a view of it
    wall, alerts = _withdrawal(tube, None, cfg)
    segs = {s["index"]: s for s in wall.segments()}
    for k in (1, 2, 3, 4):  # the first segment starts beside the camera: its first cm is never in view
        assert segs[k]["unseen_share"] < 0.05, segs[k]
    # the radius of the wall is measured (2 cm) where seen
    r = wall.radius(np.arange(wall.n_rows))[wall.observed()]
    assert abs(np.median(r) - 0.02) < 0.001
    assert [a.segment for a in alerts] in ([], [0])  # at most the first segment, never the others


def test_a_segment_whose_far_side_was_never_in_view_raises_the_alert(tube):
    cfg = CoverageConfig(segment=0.05, live_min_points=1)  # exact depth: one point in a cell is a view of it
    wall, alerts = _withdrawal(tube, (0.085, 0.17), cfg)
    segs = {s["index"]: s for s in wall.segments()}
    assert segs[2]["unseen_share"] > 0.3  # its -x half (10-15 cm) was never in view
    assert segs[4]["unseen_share"] < 0.05  # the control: after turning back
    hits = [a for a in alerts if a.segment == 2]
    assert len(hits) == 1  # once
    a = hits[0]
    # before it turned (at 8.5 cm) the camera saw 3.5 cm ahead all around: the gap starts near 12 cm
    assert 0.11 <= a.gap_from_m <= 0.125 and a.gap_to_m >= 0.145
    # the gap is on the -x side; seen from the scope (x right, looking along +z): 9 o'clock
    assert a.clock in (8, 9, 10)
    assert "segment 3 (10-15 cm)" in a.message() and "o'clock" in a.message()


def test_clock_positions_seen_from_the_scope():
    T = np.eye(4)  # x right, y down, z forward
    assert clock_position(np.array([0.0, -1.0, 0.0]), T) == 12
    assert clock_position(np.array([1.0, 0.0, 0.0]), T) == 3
    assert clock_position(np.array([0.0, 1.0, 0.0]), T) == 6
    assert clock_position(np.array([-1.0, 0.0, 0.0]), T) == 9
    assert clock_position(np.array([1.0, -1.0, 0.0]), T) in (1, 2)


def test_the_cost_of_a_frame_does_not_grow_with_the_length_mapped(tube):
    """Work per frame (rows located against, waiting points) stays bounded along a long path:
    counted, not timed."""
    cfg = CoverageConfig(segment=0.05, live_min_points=1)  # exact depth: one point in a cell is a view of it
    wall = IncrementalWall(cfg, K, NEAR_FAR)
    windows, waiting = [], []
    for T in _poses(np.arange(0.0, 0.26, 0.002), None):
        _, depth = render_pinhole(tube, K, T, W, H)
        up = wall.add_frame(T, depth)
        lo, hi = wall._window(up.s)
        windows.append(hi - lo)
        waiting.append(len(wall.wait_xyz))
    reach_rows = 2 * wall.reach / cfg.cell_length + 2
    assert max(windows) <= reach_rows and max(windows[len(windows) // 2:]) <= max(windows[:len(windows) // 2]) + 2
    assert wall.n_rows > reach_rows  # the path is longer than the window
    assert max(waiting[len(waiting) // 2:]) <= 1.5 * max(waiting[:len(waiting) // 2]) + 100


def test_the_watch_needs_a_share_and_a_margin():
    with pytest.raises(ValueError, match="threshold"):
        SegmentWatch(0.05, 1.5, 0.01)
    with pytest.raises(ValueError, match="margin"):
        SegmentWatch(0.05, 0.2, -1)


def test_a_cell_needs_live_min_points_to_count_as_observed(tube):
    """Cells with fewer depth points than coverage.live_min_points stay unseen (noise guard)."""
    seen = {}
    for k in (1, 3):
        wall = IncrementalWall(CoverageConfig(segment=0.05, live_min_points=k), K, NEAR_FAR)
        for T in _poses(np.arange(0.0, 0.1, 0.004), None):
            wall.add_frame(T, render_pinhole(tube, K, T, W, H)[1])
        wall.finish()
        seen[k] = wall.observed()
    assert np.all(seen[1] | ~seen[3]) and seen[3].sum() < seen[1].sum()
    with pytest.raises(Exception, match="live_min_points"):
        CoverageConfig(live_min_points=0)
