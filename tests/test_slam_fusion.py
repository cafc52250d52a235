"""TSDF fusion, fragment scheduling and surface coverage on analytic scenes.

The tube scene is a colon stand-in: a camera inside an open cylinder of radius 2 cm looking
down its axis, with exact depth; its ground-truth mesh is the cylinder itself.
"""

from __future__ import annotations

import importlib.util

import numpy as np
import open3d as o3d
import pytest

from c3f_slam import geometry as g
from c3f_slam.camera.intrinsics import PinholeCamera
from c3f_slam.config import PRESETS, TSDFConfig
from c3f_slam.evaluation.surface import coverage_mesh, distance_to_mesh, sample_surface, surface_coverage
from c3f_slam.fusion.tsdf import FragmentFusion, TSDFVolume, write_mesh
from tests.scenes import plane_texture, render_plane

RADIUS = 0.02
Z_END = 0.12  # the tube ends here (metres); the camera stays near z = 0
CAM = PinholeCamera.from_fov(128, 128, 100.0)
VOXEL = PRESETS["colon"].fusion.tsdf.voxel_size
CFG = TSDFConfig(depth_max=0.06)  # colon preset, nearer far limit: small test volume


def tube_mesh(z0: float = -0.03, z1: float = Z_END, n_theta: int = 96, n_z: int = 60) -> o3d.geometry.TriangleMesh:
    """Open cylinder x^2 + y^2 = RADIUS^2, z in [z0, z1] (metres)."""
    th = np.linspace(0, 2 * np.pi, n_theta, endpoint=False)
    zs = np.linspace(z0, z1, n_z)
    V = np.array([[RADIUS * np.cos(t), RADIUS * np.sin(t), z] for z in zs for t in th])
    F = []
    for a in range(n_z - 1):
        for b in range(n_theta):
            i0, i1 = a * n_theta + b, a * n_theta + (b + 1) % n_theta
            F += [[i0, i1, i0 + n_theta], [i1, i1 + n_theta, i0 + n_theta]]
    return o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(V), o3d.utility.Vector3iVector(np.array(F)))


def render_tube(T_wc: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Exact (rgb uint8, depth metres) of the tube wall seen from a camera inside it."""
    u, v = np.meshgrid(np.arange(CAM.width), np.arange(CAM.height))
    rays = np.stack([u, v, np.ones_like(u)], -1).reshape(-1, 3).astype(float) @ np.linalg.inv(CAM.K).T
    w = rays @ T_wc[:3, :3].T
    o = T_wc[:3, 3]
    a = w[:, 0] ** 2 + w[:, 1] ** 2
    b = 2 * (o[0] * w[:, 0] + o[1] * w[:, 1])
    c = o[0] ** 2 + o[1] ** 2 - RADIUS**2
    with np.errstate(divide="ignore", invalid="ignore"):
        s = (-b + np.sqrt(b * b - 4 * a * c)) / (2 * a)
    hit = o + s[:, None] * w
    ok = np.isfinite(s) & (s > 0) & (hit[:, 2] <= Z_END)
    depth = np.where(ok, s, 0.0).reshape(CAM.height, CAM.width).astype(np.float32)
    ang = np.arctan2(hit[:, 1], hit[:, 0])
    stripes = (np.sin(ang * 6) * np.cos(hit[:, 2] * 400) + 1) / 2
    rgb = np.stack([180 + 60 * stripes, 90 + 80 * stripes, 80 * (1 - stripes)], -1)
    rgb = np.where(ok[:, None], rgb, 0).reshape(CAM.height, CAM.width, 3).astype(np.uint8)
    return rgb, depth


def tube_poses(n: int = 8) -> np.ndarray:
    """Camera-to-world poses moving forward 4 mm per frame, slightly off-axis and turning."""
    return np.array([
        g.make_pose(g.axis_angle_to_matrix([0.02 * np.sin(k), 0.03 * np.cos(k), 0.1 * k]),
                    [0.002 * np.cos(k), 0.002 * np.sin(k), 0.004 * k])
        for k in range(n)
    ])


def _radial_error(mesh: o3d.geometry.TriangleMesh) -> np.ndarray:
    V = np.asarray(mesh.vertices)
    return np.abs(np.hypot(V[:, 0], V[:, 1]) - RADIUS)


@pytest.fixture(scope="module")
def tube_fused():
    vol = TSDFVolume(CFG)
    poses = tube_poses()
    for T in poses:
        rgb, depth = render_tube(T)
        vol.integrate(rgb, depth, CAM.K, T)
    return vol.extract_mesh(), poses


# ---------------------------------------------------------------------- TSDF


def test_presets_are_metric():
    colon, room = PRESETS["colon"].fusion.tsdf, PRESETS["room"].fusion.tsdf
    assert colon.voxel_size == 0.001 and colon.trunc == 0.004
    assert room.voxel_size == 0.01 and room.trunc == 0.04
    with pytest.raises(ValueError):
        TSDFConfig(voxel_size=0.0)


def test_empty_volume_gives_empty_mesh():
    vol = TSDFVolume("colon")
    assert len(vol.extract_mesh().vertices) == 0
    vol.integrate(None, np.zeros((8, 8), np.float32), CAM.K, np.eye(4))  # no valid depth: ignored
    assert vol.n_integrated == 0


def test_tube_mesh_lies_on_true_surface(tube_fused):
    mesh, poses = tube_fused
    err = _radial_error(mesh)
    assert len(err) > 2000
    assert np.percentile(err, 99) < VOXEL and err.max() < 1.5 * VOXEL
    assert mesh.has_vertex_colors() and mesh.has_vertex_normals()
    V = np.asarray(mesh.vertices)
    assert V[:, 2].max() < poses[-1][2, 3] + CFG.depth_max + VOXEL  # nothing beyond the far limit


def test_plane_colours_and_depth():
    """Plane scene with GT poses: vertices within a voxel of z = 5 cm, colours = texture (RGB order)."""
    cam = PinholeCamera.from_fov(48, 48, 90.0)
    tex = plane_texture(seed=3)
    vol = TSDFVolume("colon")
    for i in range(4):
        T = g.make_pose(g.axis_angle_to_matrix([0.0, 0.01 * i, 0.0]), [0.002 * i, 0.0, 0.0])
        rgb, depth = render_plane(cam, T, tex, 0.05, extent=0.1)
        vol.integrate(rgb, depth, cam.K, T)
    mesh = vol.extract_mesh()
    V, C = np.asarray(mesh.vertices), np.asarray(mesh.vertex_colors)
    assert len(V) > 1000 and np.abs(V[:, 2] - 0.05).max() < VOXEL
    n = tex.shape[0]
    px = np.clip(np.rint((V[:, :2] + 0.1) / 0.2 * (n - 1)).astype(int), 0, n - 1)
    expected = tex[px[:, 1], px[:, 0]] / 255.0
    assert np.median(np.abs(C - expected)) < 0.05
    assert np.median(np.abs(C - expected[:, ::-1])) > np.median(np.abs(C - expected))  # not BGR


def test_write_mesh_atomic(tmp_path, tube_fused):
    mesh, _ = tube_fused
    out = tmp_path / "mesh.ply"
    write_mesh(mesh, out)
    back = o3d.io.read_triangle_mesh(str(out))
    assert len(back.triangles) == len(mesh.triangles) and back.has_vertex_colors()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mesh.ply"]


# ---------------------------------------------------------------------- fragments


def test_fragment_fusion_fuses_the_chosen_fragments_with_final_poses_at_the_end():
    poses = tube_poses(8)
    frames = {k: render_tube(T) for k, T in enumerate(poses)}
    loads: list[int] = []

    def load(k: int):
        loads.append(k)
        return frames[k]

    ff = FragmentFusion(TSDFVolume(CFG), load, CAM.K)
    for k in range(8):
        ff.add_frame(k // 2, k)  # fragments {0,1}, {2,3}, {4,5}, {6,7}
    assert loads == [] and ff.fragments == {0: [0, 1], 1: [2, 3], 2: [4, 5], 3: [6, 7]}  # nothing fused yet
    mesh = ff.finalize(lambda k: poses[k], fragments=[3, 0, 1, 2, 7])  # 7: no such fragment
    assert loads == list(range(8))  # each frame read once, in fragment order
    assert np.percentile(_radial_error(mesh), 99) < VOXEL
    # another mesh starts from an empty volume; a frame without a pose (unregistered) is skipped
    ff.finalize(lambda k: None if k == 0 else poses[k], fragments=[0])
    assert ff.volume.n_integrated == 1 and loads[8:] == [1]


def test_fragment_fusion_reads_ahead_without_changing_the_mesh(tmp_path):
    """finalize reads the next frame while it fuses one: the mesh is the serial loop's (the same
    triangles, positions and colours; Open3D lists them in another order from one run to the
    next), at most one frame is read ahead, and an unreadable frame's error reaches the caller."""
    import threading

    from benchmarks.protocols.trajectory_identity import mesh_fingerprint

    poses = tube_poses(6)
    frames = {k: render_tube(T) for k, T in enumerate(poses)}
    serial = TSDFVolume(CFG)
    for k in range(6):
        serial.integrate(*frames[k], CAM.K, poses[k])
    fused: list[int] = []
    read: list[int] = []
    lock = threading.Lock()

    class Counting(TSDFVolume):
        def integrate(self, rgb, depth, K, T_wc):
            fused.append(len(fused))
            super().integrate(rgb, depth, K, T_wc)

    def load(k: int):
        with lock:
            read.append(k)
            assert len(read) <= len(fused) + 2  # the frame being fused and the next one
        return frames[k]

    ff = FragmentFusion(Counting(CFG), load, CAM.K)
    for k in range(6):
        ff.add_frame(0, k)
    mesh, want = ff.finalize(lambda k: poses[k]), serial.extract_mesh()
    assert read == list(range(6)) and len(fused) == 6
    write_mesh(mesh, tmp_path / "ahead.ply")
    write_mesh(want, tmp_path / "serial.ply")
    assert len(mesh.triangles) > 1000
    assert mesh_fingerprint(tmp_path / "ahead.ply") == mesh_fingerprint(tmp_path / "serial.ply")

    def broken(k: int):
        if k == 3:
            raise OSError("frame 3: unreadable")
        return frames[k]

    ff.load_frame = broken
    with pytest.raises(OSError, match="frame 3"):
        ff.finalize(lambda k: poses[k])


# ---------------------------------------------------------------------- coverage


def _visible_share(points: np.ndarray, poses: np.ndarray) -> float:
    """Share of points inside some camera's image with depth in (0, depth_max] (no occlusion
    inside a tube seen from within)."""
    seen = np.zeros(len(points), bool)
    for T in poses:
        uv, z = g.project(g.transform_points(g.invert_pose(T), points), CAM.K)
        with np.errstate(invalid="ignore"):
            seen |= (z > 0) & (z <= CFG.depth_max) & (uv[:, 0] >= -0.5) & (uv[:, 0] < CAM.width - 0.5) \
                & (uv[:, 1] >= -0.5) & (uv[:, 1] < CAM.height - 0.5)
    return float(seen.mean())


def test_coverage_of_known_patch():
    """The metric itself: a reconstruction equal to the tube between z = 2 and 7 cm covers
    (5 cm + 2 x threshold) / 15 cm of it; a copy 1 mm off still counts, 4 mm off does not."""
    gt = tube_mesh()
    patch = tube_mesh(0.02, 0.07, n_theta=192, n_z=100)
    cov = surface_coverage(gt, patch, threshold=0.0025, n_samples=20_000)
    assert cov.share == pytest.approx((0.05 + 0.005) / 0.15, abs=0.01)
    assert cov.gt_area_m2 == pytest.approx(2 * np.pi * RADIUS * 0.15, rel=0.01)
    assert cov.threshold == 0.0025 and cov.n_samples == 20_000
    for scale, expected in ((1.05, 0.367), (1.2, 0.0)):  # radius 21 mm, 24 mm
        off = o3d.geometry.TriangleMesh(patch)
        off.vertices = o3d.utility.Vector3dVector(np.asarray(patch.vertices) * [scale, scale, 1.0])
        assert surface_coverage(gt, off, n_samples=5000).share == pytest.approx(expected, abs=0.02)
    assert surface_coverage(gt, gt, n_samples=2000).share == 1.0
    assert surface_coverage(gt, o3d.geometry.TriangleMesh(), n_samples=2000).share == 0.0


def test_coverage_of_fused_tube(tube_fused):
    """Fused tube: coverage follows what the cameras saw, minus thin bands at the image and
    depth limits (marching cubes needs observed voxels on both sides of the surface)."""
    mesh, poses = tube_fused
    gt = tube_mesh()
    cov = surface_coverage(gt, mesh, threshold=0.0025, n_samples=20_000)
    pts, _ = sample_surface(gt, 20_000)
    expected = _visible_share(pts, poses)
    assert 0.3 < expected < 0.6  # the scene really has seen and unseen parts
    assert expected - 0.06 < cov.share <= expected + 0.01

    painted = coverage_mesh(gt, mesh, threshold=0.0025, max_edge=0.0015)
    V, C = np.asarray(painted.vertices), np.asarray(painted.vertex_colors)
    red = np.all(np.isclose(C, [0.9, 0.1, 0.1]), axis=1)
    assert red[V[:, 2] < -0.005].all()  # behind the first camera: unseen
    assert not red[(V[:, 2] > 0.03) & (V[:, 2] < 0.05)].any()  # in view of every frame: seen
    assert len(V) > len(gt.vertices)  # subdivided to max_edge
    d = distance_to_mesh(V[~red], mesh)
    assert d.max() <= 0.0025 + 1e-6


def test_simulator_colon_fusion_if_available(tmp_path):
    """Fusing the simulator's tiny colon with GT depth and poses hugs its GT mesh."""
    if importlib.util.find_spec("datamodules.synthetic.fixture") is None:
        pytest.skip("datamodules.synthetic.fixture not written yet")
    from c3f_slam.io import Sequence
    from datamodules.synthetic.fixture import make_tiny_sequence

    root = make_tiny_sequence(tmp_path / "colon", frames=8, size=64, seed=0)
    seq = Sequence(root)
    assert seq.has_depth and seq.has_poses and seq.mesh_path is not None
    vol = TSDFVolume("colon")
    for i in range(len(seq)):
        vol.integrate(seq.read_rgb(i), seq.read_depth(i), seq.camera.K, seq.pose(i))
    mesh = vol.extract_mesh()
    gt = o3d.io.read_triangle_mesh(str(seq.mesh_path))
    d = distance_to_mesh(np.asarray(mesh.vertices), gt)
    assert len(d) > 500
    assert np.median(d) < VOXEL and np.percentile(d, 95) < 2 * VOXEL
    assert 0.0 < surface_coverage(gt, mesh, n_samples=20_000).share < 1.0
