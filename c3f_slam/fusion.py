"""TSDF fusion (docs/design.md, Fusion) on Open3D's voxel-hashing ``VoxelBlockGrid`` and fragment scheduling.

- :class:`TSDFVolume`: integrate RGB + depth (metres) with camera-to-world poses, extract a
  vertex-coloured triangle mesh with marching cubes. Unobserved space stays empty, so
  unseen colon wall shows up as holes in the mesh (the clinical output).
- :class:`FragmentFusion`: keeps each fragment's frame list, fuses a fragment once it is
  settled (not inspected for more than ``eps_f_na`` frames and the camera farther than
  ``eps_cf_d`` metres from it), and re-fuses everything with the final poses at the end.

Defaults (:class:`~c3f_slam.config.TSDFConfig` and the presets of :mod:`c3f_slam.config.presets`),
all metres:

- colon: voxel 1 mm, truncation 4 mm, depth 1 mm..20 cm. The lumen is 2-3 cm in radius and
  haustral folds are a few mm thick: 1 mm voxels resolve folds and give ~150 voxels around
  the lumen; a 4-voxel truncation band covers DepthNet's depth noise (a few mm at a few cm)
  without merging the fold's two sides. 20 cm is the far limit of usable colonoscope depth
  (SimCol3D's depth range); the dark lumen far away is unreliable.
- room (RGB-D indoor scenes): voxel 1 cm, truncation 4 cm, depth up to 4 m.

Open3D notes (0.19): ``VoxelBlockGrid.integrate`` takes the *world-to-camera* extrinsic;
float depth must come with float colour (we pass RGB / 255, so mesh colours are in [0, 1]);
the CPU hash map grows beyond ``block_count`` on demand.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from itertools import islice
from pathlib import Path

import numpy as np
import open3d as o3d
import open3d.core as o3c

from c3f_slam.config import TSDFConfig, preset
from c3f_slam.geometry import invert_pose
from c3f_slam.io.atomic import atomic_write


class TSDFVolume:
    """Scalable TSDF with attributes tsdf, weight, colour (RGB in [0, 1]) on the CPU."""

    def __init__(self, config: TSDFConfig | str = "colon") -> None:
        self.config = preset(config).fusion.tsdf if isinstance(config, str) else config
        self._device = o3c.Device("CPU:0")
        self.reset()

    def reset(self) -> None:
        """Drop everything fused so far."""
        c = self.config
        self._vbg = o3d.t.geometry.VoxelBlockGrid(
            attr_names=("tsdf", "weight", "color"),
            attr_dtypes=(o3c.float32, o3c.float32, o3c.float32),
            attr_channels=((1), (1), (3)),
            voxel_size=c.voxel_size,
            block_resolution=c.block_resolution,
            block_count=c.block_count,
            device=self._device,
        )
        self.n_integrated = 0

    def integrate(self, rgb: np.ndarray | None, depth_m: np.ndarray, K: np.ndarray, T_wc: np.ndarray) -> None:
        """Fuse one frame: (H, W, 3) uint8 RGB (None = grey), (H, W) depth in metres
        (0/NaN = none), 3x3 intrinsics, camera-to-world pose."""
        c = self.config
        depth = np.asarray(depth_m, dtype=np.float32)
        if depth.ndim != 2:
            raise ValueError(f"depth must be (H, W), got {depth.shape}")
        depth = np.where(np.isfinite(depth) & (depth >= c.depth_min) & (depth <= c.depth_max), depth, 0.0)
        depth = np.ascontiguousarray(depth, dtype=np.float32)
        if rgb is None:
            color = np.full(depth.shape + (3,), 0.5, np.float32)
        else:
            if rgb.shape[:2] != depth.shape or rgb.ndim != 3 or rgb.shape[2] != 3:
                raise ValueError(f"rgb {rgb.shape} does not match depth {depth.shape}")
            color = np.ascontiguousarray(rgb, dtype=np.float32) / np.float32(255.0)
        if not np.any(depth > 0):
            return
        K_t = o3c.Tensor(np.asarray(K, dtype=np.float64))
        extrinsic = o3c.Tensor(invert_pose(np.asarray(T_wc, dtype=np.float64)))
        d_img = o3d.t.geometry.Image(o3c.Tensor(depth))
        c_img = o3d.t.geometry.Image(o3c.Tensor(np.ascontiguousarray(color)))
        mult = c.trunc / c.voxel_size
        blocks = self._vbg.compute_unique_block_coordinates(d_img, K_t, extrinsic, 1.0, c.depth_max, mult)
        self._vbg.integrate(blocks, d_img, c_img, K_t, K_t, extrinsic, 1.0, c.depth_max, mult)
        self.n_integrated += 1

    @property
    def n_blocks(self) -> int:
        return int(self._vbg.hashmap().size())

    def extract_mesh(self) -> o3d.geometry.TriangleMesh:
        """Marching-cubes mesh (legacy Open3D, metres, world frame) with vertex colours in
        [0, 1] and vertex normals; empty when nothing has been fused."""
        if self.n_integrated == 0 or self.n_blocks == 0:
            return o3d.geometry.TriangleMesh()
        mesh = self._vbg.extract_triangle_mesh(weight_threshold=self.config.weight_threshold).to_legacy()
        if len(mesh.vertices):
            mesh.compute_vertex_normals()
        return mesh


def write_mesh(mesh: o3d.geometry.TriangleMesh, path: str | Path) -> None:
    """Write a mesh atomically (the format follows the suffix, e.g. .ply)."""
    path = Path(path)
    with atomic_write(path) as tmp:
        if not o3d.io.write_triangle_mesh(str(tmp), mesh, write_ascii=False):
            raise OSError(f"{path}: could not write mesh")


# ---------------------------------------------------------------------- fragments

FrameLoader = Callable[[int], tuple[np.ndarray | None, np.ndarray]]
PoseLookup = Callable[[int], "np.ndarray | None"]


@dataclass
class _Fragment:
    frames: list[int] = field(default_factory=list)
    last_inspected: int = -1
    fused: bool = False


class FragmentFusion:
    """Fuse fragments into a live preview volume once they are settled (docs/design.md, Fusion).

    A fragment is settled at frame ``current`` when ``current - last_inspected > eps_f_na``
    (frames) and the current camera centre is farther than ``eps_cf_d`` (metres) from every
    camera centre of the fragment's frames. ``load_frame(index)`` returns (rgb, depth_m) of a
    frame (frames are re-read, never kept in memory); ``pose_of(index)`` returns its current
    camera-to-world pose, or None when it is not registered (then it is skipped).
    Defaults: 30 frames (1 s at 30 fps) and 5 cm (about one lumen diameter, colon); a room
    would use about 1 m.

    Bounded work per frame: only fragments not yet fused are considered, and when more than
    ``max_checks`` of them wait, :meth:`settled` looks at ``max_checks`` of them per call in
    round-robin order (a fragment may then settle a few frames late in the live preview;
    the final mesh is unaffected). None checks all of them every frame.
    """

    def __init__(
        self,
        volume: TSDFVolume,
        load_frame: FrameLoader,
        K: np.ndarray,
        eps_f_na: int = 30,
        eps_cf_d: float = 0.05,
        max_checks: int | None = 16,
    ) -> None:
        self.volume = volume
        self.load_frame = load_frame
        self.K = np.asarray(K, dtype=np.float64)
        self.eps_f_na = int(eps_f_na)
        self.eps_cf_d = float(eps_cf_d)
        self.max_checks = max_checks
        self.fragments: dict[int, _Fragment] = {}
        self._pending: dict[int, None] = {}  # not yet fused, in round-robin order

    def _get(self, fragment: int) -> _Fragment:
        f = self.fragments.get(fragment)
        if f is None:
            f = self.fragments[fragment] = _Fragment()
            self._pending[fragment] = None
        return f

    def add_frame(self, fragment: int, frame: int) -> None:
        """Record that ``frame`` belongs to ``fragment`` (and that it was inspected then)."""
        f = self._get(fragment)
        f.frames.append(frame)
        f.last_inspected = max(f.last_inspected, frame)

    def mark_inspected(self, fragment: int, frame: int) -> None:
        """The camera saw ``fragment`` again at ``frame`` (e.g. its keyframe matched)."""
        f = self._get(fragment)
        f.last_inspected = max(f.last_inspected, frame)

    @property
    def fused(self) -> list[int]:
        return sorted(k for k, f in self.fragments.items() if f.fused)

    def _far(self, fragment: _Fragment, centre: np.ndarray, pose_of: PoseLookup) -> bool:
        """Every registered camera centre of the fragment is farther than eps_cf_d (stops at
        the first near one)."""
        for fr in fragment.frames:
            T = pose_of(fr)
            if T is not None and float(np.linalg.norm(np.asarray(T)[:3, 3] - centre)) <= self.eps_cf_d:
                return False
        return True

    def settled(
        self,
        current: int,
        T_wc: np.ndarray,
        pose_of: PoseLookup,
        eligible: Iterable[int] | Callable[[int], bool] | None = None,
    ) -> list[int]:
        """Fragments (not yet fused, ``eligible`` if given: ids, or a predicate) that are
        settled at frame ``current`` with the camera at pose ``T_wc`` (at most ``max_checks``
        of the waiting fragments are looked at per call, see the class notes)."""
        if eligible is None or callable(eligible):
            allowed = eligible
        else:
            ids = eligible if isinstance(eligible, (set, frozenset, dict)) else set(eligible)
            allowed = ids.__contains__
        centre = np.asarray(T_wc, dtype=np.float64)[:3, 3]
        if self.max_checks is None or len(self._pending) <= self.max_checks:
            batch = sorted(self._pending)
        else:  # round robin: look at the first max_checks, then move them to the back
            batch = list(islice(self._pending, self.max_checks))
            for k in batch:
                del self._pending[k]
                self._pending[k] = None
        out = []
        for k in batch:
            f = self.fragments[k]
            if f.fused:
                self._pending.pop(k, None)
                continue
            if allowed is not None and not allowed(k):
                continue
            if current - f.last_inspected > self.eps_f_na and self._far(f, centre, pose_of):
                out.append(k)
        return sorted(out)

    def _fuse(self, fragment: _Fragment, pose_of: PoseLookup) -> None:
        for fr in fragment.frames:
            T = pose_of(fr)
            if T is None:
                continue
            rgb, depth = self.load_frame(fr)
            self.volume.integrate(rgb, depth, self.K, T)
        fragment.fused = True

    def step(
        self, current: int, T_wc: np.ndarray, pose_of: PoseLookup, eligible: Iterable[int] | None = None
    ) -> list[int]:
        """Fuse every settled fragment into the preview volume; returns their ids.

        Pass ``eligible`` = the fragments connected to the map (ids or a predicate), so that
        lone fragments wait.
        """
        done = self.settled(current, T_wc, pose_of, eligible)
        for k in done:
            self._fuse(self.fragments[k], pose_of)
            self._pending.pop(k, None)
        return done

    def finalize(self, pose_of: PoseLookup, fragments: Iterable[int] | None = None) -> o3d.geometry.TriangleMesh:
        """Re-fuse ``fragments`` (default: all; leave lone ones out) with the final poses from
        an empty volume, and return the mesh."""
        self.volume.reset()
        keep = sorted(self.fragments) if fragments is None else sorted(set(fragments))
        for f in self.fragments.values():
            f.fused = False
        for k in keep:
            if k in self.fragments:
                self._fuse(self.fragments[k], pose_of)
        self._pending = {k: None for k, f in sorted(self.fragments.items()) if not f.fused}
        return self.volume.extract_mesh()
