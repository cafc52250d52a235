"""TSDF fusion (docs/design.md, Fusion) on Open3D's voxel-hashing ``VoxelBlockGrid`` and fragment scheduling.

- :class:`TSDFVolume`: integrate RGB + depth (metres) with camera-to-world poses, extract a
  vertex-coloured triangle mesh with marching cubes. Unobserved space stays empty, so
  unseen colon wall shows up as holes in the mesh (the clinical output).
- :class:`FragmentFusion`: keeps each fragment's frame list and fuses the chosen fragments
  with their final poses at the end of the run.

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
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import open3d as o3d
import open3d.core as o3c

from c3f_core.atomic import atomic_write
from c3f_slam.config import TSDFConfig, preset
from c3f_slam.geometry import invert_pose


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


class FragmentFusion:
    """The frames of each fragment, and the mesh fused from them with the final poses.

    The run records each processed frame under its fragment (:meth:`add_frame`); at the end
    :meth:`finalize` fuses the chosen fragments (the main map's, or one component's) into an
    empty volume with their final poses. No volume is kept while the stream runs: nothing
    would read it, and every frame is fused once, with its final pose, per mesh made.
    ``load_frame(frame)`` returns (rgb, depth in metres) of a frame (frames are re-read,
    never kept in memory); ``pose_of(frame)`` its camera-to-world pose, or None when it is
    not registered (then it is skipped); ``K`` the 3x3 intrinsics of the loaded images (px).
    """

    def __init__(self, volume: TSDFVolume, load_frame: FrameLoader, K: np.ndarray) -> None:
        self.volume = volume
        self.load_frame = load_frame
        self.K = np.asarray(K, dtype=np.float64)
        self.fragments: dict[int, list[int]] = {}  # fragment id -> its frames, in stream order

    def add_frame(self, fragment: int, frame: int) -> None:
        """Record that ``frame`` belongs to ``fragment``."""
        self.fragments.setdefault(fragment, []).append(frame)

    def finalize(self, pose_of: PoseLookup, fragments: Iterable[int] | None = None) -> o3d.geometry.TriangleMesh:
        """Fuse ``fragments`` (default: all; leave lone ones out) with the poses of ``pose_of``
        into an empty volume, in fragment order, and return the mesh."""
        self.volume.reset()
        keep = sorted(self.fragments) if fragments is None else sorted(set(fragments))
        todo = [(frame, T) for k in keep for frame in self.fragments.get(k, ()) if (T := pose_of(frame)) is not None]
        # the next frame is read in a thread while this one is fused (both release the GIL;
        # the same frames in the same order, at most two in memory)
        with ThreadPoolExecutor(max_workers=1, thread_name_prefix="fusion-read") as reader:
            ahead = reader.submit(self.load_frame, todo[0][0]) if todo else None
            for n, (_, T) in enumerate(todo):
                rgb, depth = ahead.result()
                if n + 1 < len(todo):
                    ahead = reader.submit(self.load_frame, todo[n + 1][0])
                self.volume.integrate(rgb, depth, self.K, T)
        return self.volume.extract_mesh()
