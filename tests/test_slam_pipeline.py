"""SLAM runtime: fragment rules, end to end in RGB-D mode on the simulator,
re-localisation after black frames, and checks that the tests can fail."""

from __future__ import annotations

import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from c3f_core.errors import InputError
from c3f_slam.camera.frustum import frustum_overlap
from c3f_slam.config import preset as slam_preset
from c3f_slam.evaluation.trajectory import evaluate_trajectory
from c3f_slam.geometry import make_pose
from c3f_slam.io import Sequence, read_tum, write_tum
from c3f_slam.matching import MatchFilterConfig
from c3f_slam.pipeline import SlamConfig, run_slam
from c3f_slam.pipeline.fragments import CORRESPONDENCES, OVERLAP, SIZE, Fragment, new_fragment_reason
from c3f_slam.pipeline.frame_step import KINDS
from c3f_slam.pipeline.frontend import FrameFeatures, PairMatch, explain_match, match_frames
from c3f_slam.pipeline.odometry import OdometrySlam
from c3f_slam.pipeline.slam import FragmentSlam
from datamodules.synthetic.fixture import make_tiny_sequence

FRAMES, SIZE_PX = 36, 128
#: 128 px frames give 20-60 filtered correspondences between neighbours, so the paper's 100
#: (tuned at 512+ px) would make every frame a keyframe; the tests use 15.
CFG = dict(fragments={"min_correspondences": 15})


@pytest.fixture(scope="module")
def seq(tmp_path_factory) -> Path:
    return make_tiny_sequence(tmp_path_factory.mktemp("slam") / "seq", frames=FRAMES, size=SIZE_PX, seed=3)


def _evaluate(out: Path, seq_dir: Path) -> dict:
    st, P = read_tum(out / "trajectory.txt")
    g = Sequence(seq_dir)
    return evaluate_trajectory(st, P, g.timestamps, g.poses)


# ---------------------------------------------------------------------- unit: fragment decisions

def test_new_fragment_reason_rules():
    assert new_fragment_reason(150, 0.95, 3) is None
    assert new_fragment_reason(99, 0.95, 3) == CORRESPONDENCES  # paper: < 100 correspondences
    assert new_fragment_reason(100, 0.84, 3) == OVERLAP  # paper: < 85 % overlap
    assert new_fragment_reason(100, 0.85, 3) is None
    assert new_fragment_reason(500, None, 60, max_fragment_frames=60) == SIZE
    assert new_fragment_reason(20, 0.9, 3, min_correspondences=15) is None


def test_overlap_decides_on_synthetic_motion():
    """A fronto-parallel wall at 3 cm: small motion keeps > 85 % overlap, a 1 cm side step does not."""
    K = np.array([[32.0, 0, 31.5], [0, 32.0, 31.5], [0, 0, 1]])
    depth = np.full((64, 64), 0.03)
    small = frustum_overlap(depth, K, make_pose(np.eye(3), [0.001, 0, 0]), np.eye(4))
    big = frustum_overlap(depth, K, make_pose(np.eye(3), [0.01, 0, 0]), np.eye(4))
    assert small > 0.85 and new_fragment_reason(200, small, 2) is None
    assert big < 0.85 and new_fragment_reason(200, big, 2) == OVERLAP


def _feat(i: int, n: int = 20) -> FrameFeatures:
    return FrameFeatures(i, float(i), np.zeros((n, 2), np.float32), np.zeros((n, 128), np.uint8),
                         np.zeros((n, 3), np.float32))


def test_explain_match_reports_each_step():
    """A known rigid motion is recovered with every correspondence; each failure names its step."""
    rng = np.random.default_rng(3)
    n = 40
    desc = rng.gamma(0.6, 30.0, (n, 128)).clip(0, 255).astype(np.uint8)
    pts_j = (rng.uniform(-0.01, 0.01, (n, 3)) + [0, 0, 0.03]).astype(np.float32)
    T = make_pose(cv2.Rodrigues(np.array([0.0, 0.05, 0.02]))[0], [0.002, -0.001, 0.0005])
    pts_i = (pts_j @ T[:3, :3].T + T[:3, 3]).astype(np.float32)
    fi = FrameFeatures(0, 0.0, np.zeros((n, 2), np.float32), desc, pts_i)
    fj = FrameFeatures(1, 1.0, np.zeros((n, 2), np.float32), desc, pts_j)
    cfg = MatchFilterConfig()
    a = explain_match(fi, fj, cfg)
    assert a.reason == "" and a.candidates == n and a.filtered == n and a.match is not None
    np.testing.assert_allclose(a.match.T_ij, T, atol=1e-5)
    m, k = match_frames(fi, fj, cfg)
    assert k == n and np.allclose(m.T_ij, a.match.T_ij)
    # scrambled 3D points: descriptors agree, geometry does not
    bad = FrameFeatures(1, 1.0, fj.xy, desc, rng.permutation(pts_j))
    a = explain_match(fi, bad, cfg)
    assert a.match is None and a.candidates == n and a.filtered < cfg.min_matches
    assert "pairwise-consistent" in a.reason and match_frames(fi, bad, cfg) == (None, 0)
    few = FrameFeatures(1, 1.0, fj.xy[:5], desc[:5], pts_j[:5])
    assert explain_match(fi, few, cfg).reason.startswith("too few keypoints")


def test_fragment_chains_and_optimises_relative_to_keyframe():
    rng = np.random.default_rng(0)
    pts = rng.uniform(-0.01, 0.01, (30, 3)) + [0, 0, 0.03]
    step = make_pose(np.eye(3), [0.002, 0, 0])  # T_{i-1,i}
    frag = Fragment(0, _feat(0), np.zeros((4, 4)), "first")
    for i in range(1, 4):
        extra = [(0, PairMatch(np.linalg.matrix_power(step, i), pts, 30))]
        frag.add_frame(_feat(i), PairMatch(step, pts, 30), extra)
    frag.close(SlamConfig().posegraph)
    assert frag.features is None and frag.rel_poses.shape == (4, 4, 4)
    np.testing.assert_allclose(frag.pose(0), np.eye(4), atol=1e-9)
    np.testing.assert_allclose(frag.pose(3)[:3, 3], [0.006, 0, 0], atol=1e-6)


# ---------------------------------------------------------------------- end to end

@pytest.mark.e2e
def test_rgbd_end_to_end_full_system(seq, tmp_path):
    cfg = slam_preset("colon", **CFG)
    s = run_slam(seq, tmp_path / "full", cfg, progress=False)
    ev = _evaluate(tmp_path / "full", seq)
    length = ev["gt_length_m"]
    assert s["registered_share"] >= 0.9
    assert ev["ate_sim3"]["rmse_m"] < 0.05 * length, ev  # measured: about 0.2 % of ~9 cm
    assert ev["ate_se3"]["rmse_m"] < 0.002
    assert s["fragments"] >= 2 and s["keyframes"] == s["fragments"]
    d = s["frame_decisions"]  # the back-end's decision per processed frame, by kind
    assert sum(d[k] for k in KINDS) == s["processed"] and d["lost"] == 0
    assert d["keyframe"] + d["lone"] == s["keyframes"] and d["lone"] == s["lone_created"] == 1  # the first frame
    assert d["attached"] == s["attached_fragments"] == 0 and d["rejoined"] == s["breaks_rejoined"]
    assert set(s["timings"]) >= {"io", "keypoints", "matching", "posegraph", "fusion"}
    assert s["mesh_triangles"] > 0 and (tmp_path / "full" / "mesh.ply").is_file()
    assert (tmp_path / "full" / "keyframe_graph.png").is_file()


def test_odometry_baseline_and_injected_wrong_edge(seq, tmp_path):
    """The baseline tracks well; one wrong relative pose in its chain raises the ATE a lot
    (so the ATE checks above can fail)."""
    cfg = slam_preset("colon", mode="odometry", fusion={"enabled": False}, **CFG)
    s = run_slam(seq, tmp_path / "odo", cfg, progress=False)
    clean = _evaluate(tmp_path / "odo", seq)["ate_sim3"]["rmse_m"]
    d = s["frame_decisions"]
    assert d["extended"] == s["processed"] - s["lost_frames"] and d["lost"] == s["lost_frames"]

    class Broken(OdometrySlam):
        def __init__(self, *a, **k):
            super().__init__(*a, **k)
            good = self.match

            def match(fa, fb):
                m, n = good(fa, fb)
                if m is not None and fb.index == FRAMES // 2:
                    bad = make_pose(cv2.Rodrigues(np.array([0.0, 0.3, 0.0]))[0], m.T_ij[:3, 3] + 0.005)
                    m = PairMatch(bad @ m.T_ij, m.points_j, m.n)
                return m, n
            self.match = match

    run_slam(seq, tmp_path / "odo_bad", cfg, progress=False, slam_factory=Broken)
    broken = _evaluate(tmp_path / "odo_bad", seq)["ate_sim3"]["rmse_m"]
    assert clean < 0.002
    assert broken > 5 * clean and broken > 0.003


def test_blas_threads_are_capped_during_a_run_and_restored(seq, tmp_path):
    from threadpoolctl import threadpool_info, threadpool_limits

    def blas_threads() -> list[int]:
        return [i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"]

    outer = threadpool_limits(limits=2, user_api="blas")  # a known setting to change and restore
    before = blas_threads()
    assert before and all(n == 2 for n in before), before
    seen: list[list[int]] = []

    class Watching(OdometrySlam):
        def add(self, frame):
            seen.append(blas_threads())
            return super().add(frame)

    cfg = slam_preset("colon", mode="odometry", fusion={"enabled": False}, **CFG)
    run_slam(seq, tmp_path / "b1", cfg.with_(frames={"max_frames": 4}), progress=False, slam_factory=Watching)
    assert seen and all(all(n == 1 for n in t) for t in seen), seen
    assert blas_threads() == before
    seen.clear()
    run_slam(seq, tmp_path / "b0", cfg.with_(blas_threads=None, frames={"max_frames": 4}), progress=False,
             slam_factory=Watching)
    assert seen and all(t == before for t in seen)
    outer.restore_original_limits()
    with pytest.raises(InputError, match="blas_threads"):
        SlamConfig(blas_threads=0)


def test_false_loop_closure_is_pruned(seq, tmp_path):
    """A wrong keyframe match (uncertain loop edge) is removed by the line process and
    reported; the trajectory stays accurate."""
    class FalseLoop(FragmentSlam):
        def __init__(self, *a, **k):
            super().__init__(*a, **k)
            good = self.match

            def match(fa, fb):
                m, n = good(fa, fb)
                if fa.index == 0 and fb.index > FRAMES // 2 and m is None:
                    return PairMatch(make_pose(np.eye(3), [0.0, 0.0, 0.0]), fb.points[:40].astype(float), 40), 40
                return m, n
            self.match = match

    cfg = slam_preset("colon", fusion={"enabled": False}, **CFG)
    s = run_slam(seq, tmp_path / "loop", cfg, progress=False, slam_factory=FalseLoop)
    ev = _evaluate(tmp_path / "loop", seq)
    assert s["loop_edges"] >= 1 and s["pruned_edges"] >= 1, s
    assert ev["ate_sim3"]["rmse_m"] < 0.05 * ev["gt_length_m"]


def _with_black_run(src: Path, dst: Path, after: int, n_black: int) -> Path:
    """Copy of ``src`` with ``n_black`` black frames inserted after frame ``after``."""
    seq = Sequence(src)
    (dst / "rgb").mkdir(parents=True)
    (dst / "depth").mkdir()
    order = list(range(after + 1)) + [-1] * n_black + list(range(after + 1, len(seq)))
    poses = []
    for k, i in enumerate(order):
        name = f"{k:06d}.png"
        if i < 0:
            cv2.imwrite(str(dst / "rgb" / name), np.zeros((seq.camera.height, seq.camera.width, 3), np.uint8))
            shutil.copy(seq.depth_paths[after], dst / "depth" / name)
            poses.append(seq.poses[after])
        else:
            shutil.copy(seq.rgb_paths[i], dst / "rgb" / name)
            shutil.copy(seq.depth_paths[i], dst / "depth" / name)
            poses.append(seq.poses[i])
    write_tum(dst / "poses.txt", np.arange(len(order)) / 30.0, np.array(poses))
    shutil.copy(src / "camera.json", dst / "camera.json")
    shutil.copy(src / "mesh.ply", dst / "mesh.ply")
    return dst


@pytest.mark.parametrize("appearance_only", [False, True, None], ids=["all-keyframes", "appearance-top-3", "linked"])
def test_black_run_relocalises_to_the_map(seq, tmp_path, appearance_only):
    """With the track broken at skipped frames (``rejoin.across_skipped`` false), the first
    keyframe after the black frames has no odometry link; it joins the map by matching earlier
    keyframes: all of them (small map), or, with the candidates cut to the appearance top 3 (no
    recent, no spatial ones), through the global appearance score alone. By default (``linked``)
    the frame after them is matched to the last one before them and the track goes on."""
    after, n_black = FRAMES // 2, 5
    dst = _with_black_run(seq, tmp_path / "black", after, n_black)
    extra = dict(candidates={"max_candidates": 3, "recent": 0, "spatial": 0}) if appearance_only else {}
    if appearance_only is not None:
        extra["rejoin"] = {"across_skipped": False}
    cfg = slam_preset("colon", fusion={"enabled": False}, **CFG, **extra)
    s = run_slam(dst, tmp_path / "out", cfg, progress=False)
    assert s["skipped_black"] == n_black
    if appearance_only is None:
        assert s["tracking_breaks"] == 0 and s["relocalised_keyframes"] == 0
    else:
        assert s["relocalised_keyframes"] >= 1  # a keyframe with no odometry link joined the map
    st, P = read_tum(tmp_path / "out" / "trajectory.txt")
    resumed = np.arange(after + 1 + n_black, FRAMES + n_black) / 30.0
    assert np.isin(np.round(resumed, 6), np.round(st, 6)).mean() >= 0.9  # frames after the gap registered
    assert s["registered_share_of_usable"] >= 0.9
    ev = _evaluate(tmp_path / "out", dst)
    assert ev["ate_sim3"]["rmse_m"] < 0.05 * ev["gt_length_m"]



@pytest.mark.slow
@pytest.mark.parametrize("bounded", [True, False])
def test_readme_first_example_keeps_its_close_up_in_one_map(tmp_path, bounded):
    """README's first example (seq1, 300 frames, 128 px, seed 7, 15 % of the colon, a close-up
    in the middle) at default settings registers >= 95 % of its frames in one map, ATE < 1 % of
    the path. With the simulator's former event timing (``bounded`` False: ramps fixed in
    frames, the close-up turning up to 38 deg per frame) the close-up breaks tracking: re-joining
    across the break keeps the frames before it in the map (94.7 % measured before guided
    matching; 54.3 % without re-joining: the frames before the close-up were a lone component)."""
    from datamodules.synthetic.generate import generate_sequence
    from datamodules.synthetic.params import SIM_SETTINGS

    sets = ["seed=7", "camera.width=128", "camera.height=128", "path.frames=300", "path.coverage=0.15"]
    if not bounded:
        sets += ["path.max_turn_rate=none", "path.max_event_speed=none"]
    p = SIM_SETTINGS.resolve("seq1", sets=sets)
    seq_dir = generate_sequence(p, tmp_path / "seq1", progress=False)
    shares = {}
    for rejoin in (True, False) if not bounded else (True,):
        cfg = slam_preset("colon", fusion={"enabled": False}, rejoin={"enabled": rejoin})
        out = tmp_path / f"out_{rejoin}"
        s = run_slam(seq_dir, out, cfg, progress=False)
        shares[rejoin] = s["registered_share_of_usable"]
        if rejoin:
            ev = _evaluate(out, seq_dir)
            assert ev["ate_sim3"]["rmse_m"] < 0.01 * ev["gt_length_m"]
    if bounded:
        assert shares[True] >= 0.95, shares
    else:
        assert shares[True] >= 0.9 and shares[False] < 0.6, shares


def test_intra_fragment_targets_are_bounded():
    from c3f_slam.pipeline.fragments import intra_fragment_targets

    assert intra_fragment_targets(1) == [] and intra_fragment_targets(2) == [0]
    assert intra_fragment_targets(4) == [0, 1, 2]  # keyframe + the two before the previous (3)
    assert intra_fragment_targets(10, all_pairs=True) == list(range(9))
    assert intra_fragment_targets(10, recent=0, spaced=0) == [0]  # keyframe only
    for n in range(2, 200):
        t = intra_fragment_targets(n)
        assert t == sorted(set(t)) and 0 in t and n - 1 not in t and len(t) <= 1 + 2 + 8
        assert all(0 <= i < n - 1 for i in t)
    assert intra_fragment_targets(60, spaced=3) == [0, 3, 22, 41, 57, 58]  # every 19th of 1..56, from 1 + 59 % 19
    assert intra_fragment_targets(61, spaced=3) == [0, 4, 23, 42, 58, 59]  # the next frame: other older frames
    hit = set().union(*(intra_fragment_targets(n, spaced=3) for n in range(40, 60)))
    assert len(hit & set(range(1, 37))) >= 18  # over 20 frames, half the older frames took a turn
