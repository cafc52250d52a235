"""The procedural colonoscopy simulator (datamodules.synthetic): exact ground truth,
determinism, geometry (occluding folds, camera inside the lumen), CLI errors."""

from __future__ import annotations

import filecmp
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import open3d as o3d
import pytest

from c3f_core.errors import InputError
from c3f_core.settings import tree_from_mapping
from c3f_slam import geometry as g
from c3f_slam.camera.intrinsics import PinholeCamera
from c3f_slam.frames.preprocess import specular_mask
from c3f_slam.geometry import relative_motion
from c3f_slam.io import Sequence
from datamodules.synthetic import generate_sequence, get_preset, make_tiny_sequence, tiny_params
from datamodules.synthetic.__main__ import main as cli_main
from datamodules.synthetic.camera_path import plan_path
from datamodules.synthetic.colon import build_colon
from datamodules.synthetic.generate import read_event_labels
from datamodules.synthetic.noise import stream
from datamodules.synthetic.params import PAPER_TABLE, PRESETS, SIM_SETTINGS, ColonParams, PathParams, SimParams
from datamodules.synthetic.render import cast_depth, make_scene
from datamodules.synthetic.scene import build_scene, render_frames

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def tiny(tmp_path_factory) -> Path:
    return make_tiny_sequence(tmp_path_factory.mktemp("sim") / "tiny", frames=8, size=64, seed=0)


def _mesh_scene(path: Path) -> o3d.t.geometry.RaycastingScene:
    mesh = o3d.io.read_triangle_mesh(str(path))
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(mesh))
    return scene


# ---------------------------------------------------------------------- ground truth


def test_tiny_fixture_loads_with_depth_and_poses(tiny):
    seq = Sequence(tiny, min_frames=3)
    assert len(seq) == 8 and seq.has_depth and seq.has_poses and seq.mesh_path is not None
    assert (seq.camera.width, seq.camera.height) == (64, 64)
    assert seq.read_rgb(0).shape == (64, 64, 3)
    for i in range(len(seq)):
        d = seq.read_depth(i)
        assert (d > 0).all(), "the closed tube leaves no pixel without depth"
        assert 0.002 < d.min() and d.max() < 0.2
    steps = np.linalg.norm(np.diff(seq.poses[:, :3, 3], axis=0), axis=1)
    assert (steps > 0.001).all() and (steps < 0.008).all(), steps  # a few mm per frame
    assert (seq.root / "params.json").is_file() and (seq.root / "frames.csv").is_file()


def test_depth_backprojects_onto_the_mesh(tiny):
    """Every depth pixel, back-projected with K and the pose, lies on mesh.ply."""
    seq = Sequence(tiny)
    scene = _mesh_scene(seq.mesh_path)
    dists = []
    for i in range(0, len(seq), 3):
        pts = g.backproject(seq.read_depth(i), seq.camera.K).reshape(-1, 3)
        pw = g.transform_points(seq.pose(i), pts)
        dists.append(scene.compute_distance(o3d.core.Tensor(pw.astype(np.float32))).numpy())
    d = np.concatenate(dists)
    # 0.1 mm depth quantisation bounds the error by ~0.05 mm along the ray
    assert np.median(d) < 5e-5 and np.percentile(d, 99) < 1.5e-4 and d.max() < 5e-4, (np.median(d), d.max())


def test_poses_are_proper_rotations_and_camera_stays_inside(tiny):
    seq = Sequence(tiny)
    assert all(g.is_rotation(T[:3, :3]) for T in seq.poses)
    scene = _mesh_scene(seq.mesh_path)
    centres = o3d.core.Tensor(seq.poses[:, :3, 3].astype(np.float32))
    assert (scene.compute_occupancy(centres, nsamples=3).numpy() == 1).all(), "camera left the lumen"
    min_wall = tiny_params().path.min_wall_distance
    assert (scene.compute_distance(centres).numpy() >= min_wall * 0.999).all()


def test_same_seed_gives_byte_identical_files(tmp_path, tiny):
    again = make_tiny_sequence(tmp_path / "again", frames=8, size=64, seed=0)
    names = ["camera.json", "poses.txt", "mesh.ply", "params.json", "frames.csv"]
    names += [f"rgb/{i:06d}.png" for i in range(8)] + [f"depth/{i:06d}.png" for i in range(8)]
    match, mismatch, errors = filecmp.cmpfiles(tiny, again, names, shallow=False)
    assert not mismatch and not errors, (mismatch, errors)
    other = make_tiny_sequence(tmp_path / "other", frames=8, size=64, seed=1)
    assert (other / "rgb/000003.png").read_bytes() != (tiny / "rgb/000003.png").read_bytes()


@pytest.mark.e2e
def test_cli_in_a_new_process_reproduces_the_fixture(tmp_path, tiny):
    """Same seed + parameters through the CLI, in another process: same bytes."""
    out = tmp_path / "cli"
    cmd = [sys.executable, "-m", "datamodules.synthetic", "generate", "--config", str(tiny / "params.json"),
           "--out", str(out), "--no-progress"]
    res = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    for name in ["poses.txt", "rgb/000005.png", "depth/000005.png", "mesh.ply"]:
        assert (out / name).read_bytes() == (tiny / name).read_bytes(), name


def test_views_of_one_surface_agree(tiny):
    """The texture is attached to the surface: warping frame 4 into frame 3 with the true
    depth and poses lines up the fine texture (zero-mean NCC of high-passed images; the
    moving light changes the smooth shading), a wrong depth or a 2-px shift does not."""
    import cv2

    seq = Sequence(tiny)
    K = seq.camera.K

    def highpass(rgb):
        x = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY).astype(np.float32)
        return x - cv2.GaussianBlur(x, (0, 0), 2.0)

    ref = highpass(seq.read_rgb(3))
    src = highpass(seq.read_rgb(4))
    pts = g.backproject(seq.read_depth(3), K).reshape(-1, 3)
    scores = {}
    for name, scale, shift in (("true", 1.0, 0.0), ("depth x1.3", 1.3, 0.0), ("shift 2px", 1.0, 2.0)):
        uv, _ = g.project(g.transform_points(g.relative_pose(seq.pose(4), seq.pose(3)), pts * scale), K)
        maps = uv.reshape(64, 64, 2).astype(np.float32) + np.float32(shift)
        warped = cv2.remap(src, maps[..., 0], maps[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                           borderValue=np.nan)
        valid = np.isfinite(warped)
        valid[:6], valid[-6:], valid[:, :6], valid[:, -6:] = False, False, False, False
        a, b = warped[valid] - warped[valid].mean(), ref[valid] - ref[valid].mean()
        scores[name] = float((a * b).sum() / np.sqrt((a * a).sum() * (b * b).sum()))
    assert scores["true"] > 0.5, scores
    assert scores["true"] > scores["depth x1.3"] + 0.1 and scores["true"] > scores["shift 2px"] + 0.4, scores


# ---------------------------------------------------------------------- geometry


def _straight_colon(fold_height: float):
    p = ColonParams(length=0.2, tortuosity=0.0, radius_variation=0.0, fold_height=fold_height, fold_coverage=1.0,
                    relief=0.0, polyps=0, ring_vertices=96)
    return build_colon(p, stream(3, 1))


def test_a_fold_hides_the_wall_behind_it():
    """Camera on the axis 15 mm before a fold, looking down the lumen: the wall in the
    fold's geometric shadow (behind its crest) gets the fold's depth, not its own; the
    same wall points are seen when the colon has no folds (same seed)."""
    cam = PinholeCamera.from_fov(128, 128, 110)
    folded = _straight_colon(0.6)
    fold = folded.folds[len(folded.folds) // 2]
    ds = folded.ring_spacing
    lo, hi = int((fold.s - abs(fold.tilt) - 2 * fold.sigma) / ds), int((fold.s + abs(fold.tilt) + 2 * fold.sigma) / ds)
    j, k = np.unravel_index(np.argmin(folded.radius[lo:hi]), folded.radius[lo:hi].shape)
    j += lo  # the crest of the tallest crescent (folds are slanted: its s depends on theta)
    crest_s, r_crest = folded.s[j], folded.radius[j, k]
    r_wall = _straight_colon(0.0).radius[j, k]
    dist = 0.015
    shadow_end = crest_s + dist * (0.9 * r_wall / r_crest - 1)  # the ray over the crest meets the wall here
    start = crest_s + 4 * fold.sigma
    rows = np.arange(int(np.ceil(start / ds)), int(shadow_end / ds))
    assert len(rows) >= 3, (start, shadow_end)
    cols = (k + np.arange(-2, 3)) % len(folded.theta)
    seen = {}
    for colon in (folded, _straight_colon(0.0)):
        ang = colon.theta[cols]
        wall = (colon.centre[rows, None] + colon.radius[rows][:, cols, None]
                * (np.cos(ang)[None, :, None] * colon.normal[rows, None]
                   + np.sin(ang)[None, :, None] * colon.binormal[rows, None]))
        c, t, n, _ = colon.frame_at(crest_s - dist)
        T_wc = g.look_at(c, c + t, -n)
        depth, _ = cast_depth(make_scene(colon), cam, T_wc)
        uv, z = g.project(g.transform_points(g.invert_pose(T_wc), wall.reshape(-1, 3)), cam.K)
        px = np.round(uv).astype(int)
        assert ((px >= 0) & (px < 128)).all(), "wall points outside the view"
        rendered = depth[px[:, 1], px[:, 0]]
        seen[colon is folded] = float(np.mean(np.abs(rendered - z) < 0.001))
        if colon is folded:
            assert np.mean(rendered < z - 0.003) > 0.9, "the fold does not occlude the wall behind it"
    assert seen[True] < 0.1 and seen[False] > 0.9, seen


def test_paths_move_as_specified():
    colon = build_colon(ColonParams(length=0.4, polyps=0), stream(5, 1))
    scene = make_scene(colon)
    base = SimParams().path
    runs = {}
    for kind, loop in (("A", False), ("B", False), ("random", False), ("A", True)):
        p = PathParams(kind=kind, loop=loop, frames=160, closeups=12, bursts=12, occlusions=12, roll_events=6)
        path = plan_path(colon, p, stream(5, 3), scene)
        s = path.controls.s
        assert (path.wall_distance >= base.min_wall_distance * 0.999).all()
        assert all(g.is_rotation(T[:3, :3]) for T in path.poses)
        runs[(kind, loop)] = (s, path.labels)
    s, labels = runs[("A", False)]
    assert (np.diff(s) >= -1e-9).all() and s[-1] - s[0] > 0.1
    s, _ = runs[("B", False)]
    assert (np.diff(s) <= 1e-9).all() and s[0] - s[-1] > 0.1
    s, labels = runs[("random", False)]
    assert (np.diff(s) > 1e-5).any() and (np.diff(s) < -1e-5).any()
    assert {"closeup", "burst", "occluded"} <= set(labels)
    s, _ = runs[("A", True)]
    top = int(np.argmax(s))
    assert 0.3 * len(s) < top < 0.7 * len(s) and s[-1] - s[0] < 0.5 * (s[top] - s[0])


def test_event_labels_cover_the_fast_motion():
    """Events move the camera fastest while they ramp in and out: those frames carry the
    event's label too, so no fast motion is labelled as a plain frame (frames.csv)."""
    colon = build_colon(ColonParams(length=0.4, polyps=0), stream(5, 1))
    scene = make_scene(colon)
    p = PathParams(frames=600, coverage=0.3, closeups=8, bursts=0, occlusions=8, roll_events=0)
    path = plan_path(colon, p, stream(5, 4), scene)
    trans, rot = relative_motion(path.poses)
    plain = np.array([not (path.labels[i] or path.labels[i + 1]) for i in range(len(rot))])
    assert plain.sum() > 100 and (~plain).sum() > 30
    # plain frames move like the sequence's base motion; the fast pairs are all in events
    assert rot[plain].max() < 4 * np.median(rot[plain]) + 0.5, (rot[plain].max(), np.median(rot[plain]))
    assert trans[plain].max() < 4 * np.median(trans[plain]), (trans[plain].max(), np.median(trans[plain]))
    assert rot[~plain].max() > 2 * rot[plain].max()


def test_event_ramps_keep_the_rate_limits():
    """Ramps lengthen until events turn the view at most ``path.max_turn_rate`` deg/s and move at most
    ``path.max_event_speed`` m/s (bursts excepted) at the path's fps; without limits (None) the
    ramps keep their length in frames and close-ups turn several times faster."""
    colon = build_colon(ColonParams(length=0.4, polyps=0), stream(5, 1))
    scene = make_scene(colon)
    events = {"frames": 600, "coverage": 0.3, "closeups": 6, "bursts": 4, "occlusions": 6, "roll_events": 4}
    rot_max = {}
    for limits in ({}, {"max_turn_rate": None, "max_event_speed": None}):
        p = PathParams(**events, **limits)
        path = plan_path(colon, p, stream(5, 4), scene)
        trans, rot = relative_motion(path.poses)
        label = [path.labels[i] or path.labels[i + 1] for i in range(len(rot))]
        fast = {k: (max(r for r, x in zip(rot, label) if x == k),
                    max(t for t, x in zip(trans, label) if x == k)) for k in set(label) if k}
        rot_max[bool(limits)] = fast["closeup"][0]
        if not limits:
            assert {"closeup", "burst", "occluded", "roll"} <= set(fast), fast
            plain_rot = max(r for r, x in zip(rot, label) if not x)
            for k, (deg, metres) in fast.items():  # 120 deg/s = 4 deg/frame, 6 cm/s = 2 mm/frame at 30 fps
                assert deg < 1.2 * max(4.0, plain_rot), (k, deg)
                if k in ("closeup", "occluded"):
                    assert metres < 1.3 * 0.002 + max(t for t, x in zip(trans, label) if not x), (k, metres)
    assert rot_max[True] > 2.5 * rot_max[False], rot_max


def test_read_event_labels(tiny, tmp_path):
    """frames.csv's event column in frame order: the tiny fixture has no events; a missing file gives []."""
    assert read_event_labels(tiny) == [""] * len(Sequence(tiny))
    (tmp_path / "frames.csv").write_text("index,timestamp,s_m,event,wall_distance_mm\n"
                                         "1,0.03,0.1,closeup,5\n0,0.0,0.1,,5\n2,0.07,0.1,roll,5\n")
    assert read_event_labels(tmp_path) == ["", "closeup", "roll"]
    assert read_event_labels(tmp_path / "nothing") == []


def test_events_look_like_what_they_claim(tmp_path):
    """Close-up and fold-occlusion frames see the wall much nearer than plain frames."""
    p = tiny_params(frames=90, size=48, seed=2, **{
        "colon.length": 0.35, "path.kind": "random", "path.closeups": 25, "path.occlusions": 25,
        "path.max_step": 0.003, "path.max_turn_rate": None, "path.max_event_speed": None})  # short ramps: 90 frames
    scene = build_scene(p)
    cam = scene.camera
    med = {}
    for i, label in enumerate(scene.path.labels):
        depth, _ = cast_depth(scene.raycaster, cam, scene.path.poses[i])
        med.setdefault(label, []).append(np.median(depth))
    assert "closeup" in med and "occluded" in med
    plain = np.median(med[""])
    assert np.median(med["closeup"]) < 0.7 * plain, med
    assert np.median(med["occluded"]) < 0.8 * plain, med


# ---------------------------------------------------------------------- appearance


def test_wet_highlights_trigger_the_specular_mask():
    frames = {}
    for wet in (0.9, 0.0):
        p = tiny_params(frames=4, size=96, seed=4, appearance__wetness=wet)
        scene = build_scene(p)
        rgb, _ = scene.renderer.render(scene.path.poses[2], stream(4, 4, 2))
        frames[wet] = specular_mask(rgb, dilation_px=1).mean()
    assert frames[0.9] > 0.002 and frames[0.0] < 0.2 * frames[0.9], frames


def test_mucosa_is_pink_orange():
    p = tiny_params(frames=3, size=64, seed=1)
    scene = build_scene(p)
    rgb, _ = scene.renderer.render(scene.path.poses[1], stream(1, 4, 1))
    r, gg, b = (rgb[..., c].astype(float).mean() for c in range(3))
    assert r > gg > 0 and r > b and r > 90, (r, gg, b)


# ---------------------------------------------------------------------- parameters and CLI


def test_presets_follow_the_paper_table():
    assert set(PRESETS) == {"default", *PAPER_TABLE, "tiny"} == set(SIM_SETTINGS.presets)
    kinds = {name: get_preset(name).path.kind for name in PAPER_TABLE}
    assert kinds["seq1"] == "A" and kinds["seq3"] == "B" and kinds["seq2"] == "random"
    for name in PAPER_TABLE:
        p = get_preset(name)
        assert p == SIM_SETTINGS.tree(name) and p.preset == name
        assert p.camera.fov == 110 and p.camera.width == 512 and p.path.frames == 4500
    assert get_preset("Seq. 5").appearance.grain == 3
    assert get_preset("seq5").appearance.value < get_preset("seq1").appearance.value
    with pytest.raises(InputError, match="preset"):
        get_preset("seq9")


@pytest.mark.parametrize(
    "args, option",
    [
        (["--set", "colon.radius=-0.01"], "colon.radius"),
        (["--set", "camera.fov=180"], "camera.fov"),
        (["--set", "path.frames=0"], "path.frames"),
        (["--preset", "seq42"], "--preset"),
        (["--set", "camera.width=8"], "camera.width"),
        (["--set", "path.kind=Z"], "path.kind"),
        (["--set", "colon.nonsense=1"], "nonsense"),
        (["--set", "appearance.wetness=wet"], "appearance.wetness"),
        (["--set", "appearance.light_offset=0.02"], "appearance.light_offset"),  # more than colon.radius / 2
        (["--layout", "nope"], "layout"),
        (["--frames", "0"], "--set path.frames=N"),  # a removed flag names its replacement
    ],
)
def test_bad_parameters_fail_before_writing(tmp_path, capsys, args, option):
    out = tmp_path / "never"
    try:
        code = cli_main(["generate", "--out", str(out), "--no-progress", *args])
    except SystemExit as exc:  # usage errors (argparse)
        code = exc.code
    err = capsys.readouterr().err.strip()
    assert code == 2 and err.startswith("error: ") and option in err and "\n" not in err, err
    assert not out.exists() and not list(tmp_path.iterdir())


def test_cli_exit_code_and_message_in_a_real_process(tmp_path):
    res = subprocess.run([sys.executable, "-m", "datamodules.synthetic", "generate", "--preset", "nope",
                          "--out", str(tmp_path / "x")], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert res.returncode == 2 and res.stderr.startswith("error: argument --preset: invalid choice: 'nope'")
    assert len(res.stderr.strip().splitlines()) == 1 and not (tmp_path / "x").exists()


def test_existing_output_is_never_clobbered(tmp_path):
    out = tmp_path / "seq"
    out.mkdir()
    (out / "keep.txt").write_text("precious")
    with pytest.raises(InputError, match="not empty"):
        generate_sequence(tiny_params(frames=2, size=32), out, progress=False)
    assert (out / "keep.txt").read_text() == "precious"
    generate_sequence(tiny_params(frames=2, size=32), out, progress=False, overwrite=True)
    assert not (out / "keep.txt").exists() and len(Sequence(out)) == 2
    assert sorted(p.name for p in tmp_path.iterdir()) == ["seq"]  # no temporary folders left


def test_interrupted_run_leaves_nothing(tmp_path):
    def stop(i):
        if i == 2:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        generate_sequence(tiny_params(frames=6, size=32), tmp_path / "seq", progress=False, on_frame=stop)
    assert list(tmp_path.iterdir()) == []


def test_params_round_trip_and_overrides():
    p = SIM_SETTINGS.resolve("seq4", sets=["colon.length=0.5", "camera.fov=120", "camera.width=320",
                                           "camera.height=240", "colon.fold_height=0.4", "appearance.grain=2",
                                           "path.loop=true", "path.kind=rp"])
    assert (p.colon.length, p.camera.fov, p.camera.width, p.camera.height) == (0.5, 120.0, 320, 240)
    assert p.colon.fold_height == 0.4 and p.appearance.grain == 2.0 and p.path.loop is True
    assert p.path.kind == "random" and p.preset == "seq4" and p.seed == 4
    assert SimParams.from_dict(p.to_dict()) == p
    with pytest.raises(InputError, match="unknown setting 'bogus'"):
        SimParams.from_dict({"bogus": 1})
    with pytest.raises(InputError, match="unknown setting 'colon.bogus'"):
        tree_from_mapping(p, {"colon": {"bogus": 1}})


def test_contact_sheet_cli(tiny, tmp_path):
    out = tmp_path / "sheet.png"
    assert cli_main(["contact-sheet", str(tiny), "--out", str(out), "--count", "4", "--cols", "2", "--tile", "64"]) == 0
    import cv2

    img = cv2.imread(str(out))
    assert img.shape == (2 * 128, 2 * 64, 3)


def test_full_length_colon_is_closed_and_clear():
    """The default 1.25 m colon: closed mesh (camera centres inside), clearance kept."""
    p = tree_from_mapping(SimParams(seed=11), {"path": {"frames": 40, "kind": "random"},
                                               "camera": {"width": 32, "height": 32}})
    scene = build_scene(p)
    centres = o3d.core.Tensor(scene.path.poses[:, :3, 3].astype(np.float32))
    assert (scene.raycaster.compute_occupancy(centres, nsamples=3).numpy() == 1).all()
    assert (scene.path.wall_distance >= p.path.min_wall_distance * 0.999).all()
    depth, _ = cast_depth(scene.raycaster, scene.camera, scene.path.poses[20])
    assert (depth > 0).all() and math.isclose(scene.colon.length, 1.25, rel_tol=1e-9)


def test_motion_blur_and_offset_light_change_only_the_image():
    """Motion blur averages sub-frame renders; an offset light casts shadows. Depth and
    poses stay those of the frame's own pose."""
    base = tiny_params(frames=4, size=48, seed=6)
    ref = build_scene(base)
    ref_frames = list(render_frames(ref))
    for over in ({"motion_blur": 1.0}, {"light_offset": 0.004, "shadows": True}):
        scene = build_scene(tree_from_mapping(base, {"appearance": over}))
        assert np.allclose(scene.path.poses, ref.path.poses)
        for (i, rgb, depth), (_, rgb0, depth0) in zip(render_frames(scene), ref_frames):
            assert (depth == depth0).all()
            if i >= 1:
                assert np.abs(rgb.astype(int) - rgb0).mean() > 0.5, over
