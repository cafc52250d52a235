"""Ray casting and shading of the colon mesh (Open3D ``RaycastingScene`` + vectorised NumPy).

One ``cast_rays`` call per view gives, for every pixel, the exact ray parameter, the hit
triangle and its barycentric coordinates. Rays are built with camera-frame directions
``((u - cx)/fx, (v - cy)/fy, 1)``, so the ray parameter *is* the depth (z in the camera
frame, metres); misses (none inside the closed tube) get depth 0.

Shading (linear radiance): a point light at the lens (or ``light_offset`` metres beside it,
with shadow rays) with a cone of ``light_angle`` degrees and inverse-square falloff; a
wrapped Lambert term per channel (the sub-surface glow of mucosa); Blinn-Phong wet
highlights whose strength and sharpness follow ``wetness``, on normals perturbed by the
atlas' micro-relief. The sensor then applies automatic exposure, vignetting, bloom, a
filmic curve, sRGB gamma, a slight optical blur and grain.

Camera poses are camera-to-world 4x4 matrices (x right, y down, z forward).
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass

import cv2
import numpy as np
import open3d as o3d

from c3f_slam.camera.intrinsics import PinholeCamera
from datamodules.synthetic.colon import Colon
from datamodules.synthetic.noise import smoothstep
from datamodules.synthetic.params import AppearanceParams
from datamodules.synthetic.texture import TextureAtlas

REFERENCE_DISTANCE = 0.03  # m: irradiance equals light_intensity at this distance
FIXED_EXPOSURE = 1.9
AE_TARGET = 0.7  # auto exposure maps the 90th percentile of diffuse luminance here
WRAP = np.array([0.28, 0.10, 0.05], np.float32)  # per-channel wrap of the diffuse term
LIGHT_COLOUR = np.array([1.0, 0.97, 0.93], np.float32)
SATURATION_BOOST = np.float32(1.25)


def make_scene(colon: Colon, nthreads: int = 0) -> o3d.t.geometry.RaycastingScene:
    """A ray-casting scene holding the colon mesh (float32 vertices, as saved in mesh.ply)."""
    scene = o3d.t.geometry.RaycastingScene(nthreads=nthreads)
    scene.add_triangles(o3d.core.Tensor(colon.vertices), o3d.core.Tensor(colon.triangles.astype(np.uint32)))
    return scene


def camera_rays(camera: PinholeCamera) -> np.ndarray:
    """(3, H*W) float32 camera-frame ray directions ((u - cx)/fx, (v - cy)/fy, 1), row-major pixels."""
    u, v = np.meshgrid(np.arange(camera.width, dtype=np.float64), np.arange(camera.height, dtype=np.float64))
    d = np.stack([(u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy, np.ones_like(u)], axis=0)
    return d.reshape(3, -1).astype(np.float32)


def cast_depth(scene: o3d.t.geometry.RaycastingScene, camera: PinholeCamera, T_wc: np.ndarray,
               nthreads: int = 0, rays_cam: np.ndarray | None = None) -> tuple[np.ndarray, dict]:
    """Exact depth (H, W) float32 metres (0 = miss) seen from camera-to-world pose ``T_wc``.

    Returns the depth and Open3D's raw answer (t_hit, primitive_ids, primitive_uvs, ...).
    """
    d = camera_rays(camera) if rays_cam is None else rays_cam
    R, o = T_wc[:3, :3].astype(np.float32), T_wc[:3, 3]
    rays = np.empty((d.shape[1], 6), np.float32)
    rays[:, :3] = o
    for i in range(3):  # R @ d written out: small matmuls are slow in NumPy
        rays[:, 3 + i] = R[i, 0] * d[0] + R[i, 1] * d[1] + R[i, 2] * d[2]
    ans = scene.cast_rays(o3d.core.Tensor(rays), nthreads=nthreads)
    t = ans["t_hit"].numpy()
    depth = np.where(np.isfinite(t), t, 0.0).astype(np.float32).reshape(camera.height, camera.width)
    return depth, {"t_hit": t, "primitive_ids": ans["primitive_ids"].numpy(),
                   "primitive_uvs": ans["primitive_uvs"].numpy(), "dirs": np.ascontiguousarray(rays[:, 3:].T)}


def _facing_normals(n: np.ndarray, view: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Normalise the (3, N) normals ``n`` in place and flip those facing away from the (3, N)
    unit directions ``view`` (surface to camera); returns them and |n . view| (N,)."""
    n *= 1.0 / np.maximum(np.sqrt((n * n).sum(0)), 1e-12)
    ndv = (n * view).sum(0)
    flip = ndv < 0
    if flip.any():
        n[:, flip] *= -1.0
        ndv = np.abs(ndv)
    return n, ndv


@dataclass
class Hits:
    """Per-pixel result of casting one view's rays."""

    depth: np.ndarray  # (H, W) float32, metres along z, 0 = miss
    t: np.ndarray  # (N,) ray parameter (inf on miss)
    prim: np.ndarray  # (N,) triangle ids
    uv: np.ndarray  # (N, 2) barycentric (u, v): p = (1-u-v) v0 + u v1 + v v2
    origin: np.ndarray  # (3,)
    dirs: np.ndarray  # (3, N) world ray directions (z = 1 in the camera frame)


class Renderer:
    """Renders RGB + exact depth of a colon for camera-to-world poses."""

    def __init__(self, colon: Colon, atlas: TextureAtlas, camera: PinholeCamera, appearance: AppearanceParams,
                 scene: o3d.t.geometry.RaycastingScene | None = None, nthreads: int | None = None,
                 rays_cam: np.ndarray | None = None) -> None:
        """``rays_cam``: (3, H*W) camera-frame ray directions scaled to z = 1 for a camera that
        is not a pinhole (C3VD's fisheye); ``camera`` then only sets the frame size, vignetting
        centre and the focal length used for texture filtering. Default: ``camera``'s rays."""
        self.colon, self.atlas, self.camera, self.a = colon, atlas, camera, appearance
        self.nthreads = nthreads if nthreads is not None else (os.cpu_count() or 1)
        self.scene = scene if scene is not None else make_scene(colon)
        tri = colon.triangles.astype(np.int64)
        # per-vertex attributes (V, 12): inward normal, u-tangent, theta-tangent, u, cos, sin
        nrm = colon.vertex_normals.astype(np.float64)
        tth = colon.tangent_theta.astype(np.float64)
        tth = tth - nrm * (tth * nrm).sum(1, keepdims=True)
        tth /= np.maximum(np.linalg.norm(tth, axis=1, keepdims=True), 1e-12)
        tu = np.cross(tth, nrm)  # along increasing u for inward normals
        attrs = np.concatenate(
            [nrm, tu, tth, colon.tex_u[:, None], np.cos(colon.tex_theta)[:, None], np.sin(colon.tex_theta)[:, None]],
            axis=1).astype(np.float32)
        self.tri_attrs = np.ascontiguousarray(attrs[tri])  # (F, 3, 12): one gather per pixel
        h, w = camera.height, camera.width
        u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
        # (3, N), z = 1
        self.dirs_cam = camera_rays(camera) if rays_cam is None else np.ascontiguousarray(rays_cam, np.float32)
        if self.dirs_cam.shape != (3, h * w):
            raise ValueError(f"rays_cam must be (3, {h * w}), got {self.dirs_cam.shape}")
        norm = np.linalg.norm(self.dirs_cam.astype(np.float64), axis=0)
        self.ray_norm = norm.astype(np.float32)
        self.inv_norm = (1.0 / norm).astype(np.float32)  # = cosine of the angle to the optical axis
        self.pix_angle = (self.inv_norm**1.5 / camera.fx).astype(np.float32)  # angular pixel size, rad
        half = math.radians(appearance.light_angle) / 2
        self.cone_cos = (math.cos(half), math.cos(0.7 * half))
        r = np.sqrt(((u - camera.cx) / (w / 2)) ** 2 + ((v - camera.cy) / (w / 2)) ** 2)
        self.vignette = (1.0 - appearance.vignette * smoothstep(0.72, 1.38, r)).astype(np.float32)[..., None]
        self.wet_shininess = 40.0 + 360.0 * appearance.wetness
        self.wet_strength = 0.03 + 1.6 * appearance.wetness**1.5
        self._exposure: float | None = None

    # ------------------------------------------------------------------ geometry
    def trace(self, T_wc: np.ndarray) -> Hits:
        """Cast one ray per pixel from pose ``T_wc``; exact depth (H, W) float32."""
        depth, ans = cast_depth(self.scene, self.camera, T_wc, self.nthreads, self.dirs_cam)
        return Hits(depth, ans["t_hit"], ans["primitive_ids"], ans["primitive_uvs"],
                    np.asarray(T_wc[:3, 3], np.float64), ans["dirs"])

    # ------------------------------------------------------------------ shading
    def shade(self, hits: Hits, T_wc: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Linear radiance (H, W, 3) and its diffuse luminance (H, W) for one view.

        Works on (k, N) component rows (structure of arrays) for speed.
        """
        h, w = self.camera.height, self.camera.width
        hit = np.isfinite(hits.t)
        dist = np.where(hit, hits.t, 0.0).astype(np.float32) * self.ray_norm  # camera to surface, m
        attr = self._surface_attributes(hits, hit)
        view = -hits.dirs * self.inv_norm  # (3, N) unit, towards the camera
        n, ndv = _facing_normals(attr[0:3], view)
        tex4, nb = self._texture(attr, n, dist, ndv)
        ldir, half, irradiance = self._light(hits, T_wc, view, dist, n, hit)
        radiance, lum = self._reflect(tex4, n, nb, ldir=ldir, half=half, ndv=ndv, irradiance=irradiance)
        return np.ascontiguousarray(radiance.T).reshape(h, w, 3), lum.reshape(h, w)

    def _surface_attributes(self, hits: Hits, hit: np.ndarray) -> np.ndarray:
        """(12, N) per-pixel vertex attributes (see ``tri_attrs``) interpolated at the hit points
        (triangle 0 for misses)."""
        prim = np.where(hit, hits.prim, 0).astype(np.int32)
        bary = np.empty((len(prim), 3), np.float32)
        bary[:, 1:] = hits.uv
        bary[:, 0] = 1.0 - hits.uv[:, 0] - hits.uv[:, 1]
        attr = np.einsum("nk,nkc->nc", bary, np.take(self.tri_attrs, prim, axis=0))
        return np.ascontiguousarray(attr.T)  # (12, N)

    def _texture(self, attr: np.ndarray, n: np.ndarray, dist: np.ndarray,
                 ndv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Atlas look-up filtered by each pixel's footprint on the surface (``dist`` in metres):
        (4, N) albedo RGB + slope along u, and the (3, N) unit normals ``n`` tilted by the
        atlas' micro-relief."""
        footprint = dist * self.pix_angle / np.sqrt(np.maximum(ndv, 0.2))
        theta = cv2.phase(attr[10], attr[11]).reshape(-1)  # radians in [0, 2 pi), same for every view
        tex4, slope_v = self.atlas.sample(attr[9], theta, footprint)
        tex4 = tex4.T  # (4, N): albedo RGB, slope along u

        # micro-relief: tilt the normal by the atlas slopes along the surface directions
        nb = n - tex4[3] * attr[3:6] - slope_v * attr[6:9]
        nb *= 1.0 / np.maximum(np.sqrt((nb * nb).sum(0)), 1e-12)
        return tex4, nb

    def _light(self, hits: Hits, T_wc: np.ndarray, view: np.ndarray, dist: np.ndarray, n: np.ndarray,
               hit: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Unit directions to the light and Blinn half vectors (3, N, world frame), and the
        irradiance (N,) of the spot light (cone, inverse-square falloff, shadows when the light
        sits ``light_offset`` metres beside the lens of camera-to-world pose ``T_wc``)."""
        a = self.a
        R = T_wc[:3, :3]
        axis = R[:, 2].astype(np.float32)
        if a.light_offset > 0:
            points = hits.origin.astype(np.float32)[:, None] - view * dist
            lpos = (hits.origin + R @ np.array([a.light_offset, 0.0, 0.0])).astype(np.float32)
            lvec = lpos[:, None] - points
            dl = np.maximum(np.sqrt((lvec * lvec).sum(0)), 1e-6)
            ldir = lvec / dl
            half = ldir + view
            half *= 1.0 / np.maximum(np.sqrt((half * half).sum(0)), 1e-12)
        else:
            dl, ldir, half = np.maximum(dist, 1e-6), view, view
        cos_l = np.clip(-(axis @ ldir), 0.0, 1.0)
        c_out, c_in = self.cone_cos
        spot = smoothstep(c_out, c_in, cos_l) * (0.35 + 0.65 * cos_l)
        irradiance = (a.light_intensity * REFERENCE_DISTANCE**2) * spot / (dl * dl)
        if a.light_offset > 0 and a.shadows:
            irradiance *= self._unshadowed(points, n, lpos, hit)
        irradiance = np.where(hit, irradiance, 0.0).astype(np.float32)
        return ldir, half, irradiance

    def _reflect(self, tex4: np.ndarray, n: np.ndarray, nb: np.ndarray, *, ldir: np.ndarray, half: np.ndarray,
                 ndv: np.ndarray, irradiance: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Wrapped-Lambert diffuse plus wet Blinn-Phong highlights: radiance (3, N) and the
        luminance (N,) of its diffuse part (what auto exposure meters)."""
        ndl = (n * ldir).sum(0) * 0.7 + (nb * ldir).sum(0) * 0.3  # diffuse sees little of the micro-relief
        wrap = WRAP[:, None]
        diffuse = tex4[:3] * (np.maximum((ndl + wrap) * (1.0 / (1.0 + wrap)), 0.0) + 0.035)
        ndh = np.clip((nb * half).sum(0), 0.0, 1.0)
        norm = (self.wet_shininess + 8.0) / (8.0 * math.pi)
        fres = 0.6 + 0.4 * (1.0 - ndv) ** 5
        spec = cv2.pow(ndh, self.wet_shininess).reshape(-1) * fres * np.float32(self.wet_strength * norm)
        rad_diffuse = diffuse * irradiance
        lum = np.array([0.2126, 0.7152, 0.0722], np.float32) @ rad_diffuse
        radiance = (rad_diffuse + spec * irradiance) * LIGHT_COLOUR[:, None]
        return radiance, lum

    def _unshadowed(self, points: np.ndarray, n: np.ndarray, lpos: np.ndarray, hit: np.ndarray) -> np.ndarray:
        """1 where the light is visible from the (3, N) surface points, else 0."""
        start = (points + n * 2e-5).T
        rays = np.concatenate([start, lpos[None] - start], axis=1).astype(np.float32)
        occ = self.scene.test_occlusions(o3d.core.Tensor(rays), tnear=0.0, tfar=0.999, nthreads=self.nthreads).numpy()
        return np.where(occ & hit, 0.0, 1.0).astype(np.float32)

    # ------------------------------------------------------------------ sensor
    def expose(self, radiance: np.ndarray, lum: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Linear radiance (H, W, 3) -> uint8 sRGB frame (auto exposure keeps a state)."""
        a = self.a
        h, w = lum.shape
        centre = lum[h // 8 : h - h // 8, w // 8 : w - w // 8]
        p90 = float(np.percentile(centre, 90)) if centre.size else 1.0
        auto = AE_TARGET / max(p90, 1e-4)
        target = math.exp((1 - a.auto_exposure) * math.log(FIXED_EXPOSURE) + a.auto_exposure * math.log(auto))
        target = min(max(target, 0.05), 40.0)
        if self._exposure is None:
            self._exposure = target
        else:  # the light control follows within a few frames
            self._exposure = math.exp(0.6 * math.log(self._exposure) + 0.4 * math.log(target))
        x = radiance * np.float32(self._exposure) * self.vignette
        if a.bloom > 0:
            bright = np.maximum(x - 1.0, 0.0)
            s = w / 256.0
            small = cv2.resize(bright, (max(w // 4, 1), max(h // 4, 1)), interpolation=cv2.INTER_AREA)
            wide = cv2.resize(cv2.GaussianBlur(small, (0, 0), 2.0 * s), (w, h), interpolation=cv2.INTER_LINEAR)
            glow = 0.6 * cv2.GaussianBlur(bright, (0, 0), 2.0 * s) + 0.4 * wide
            x = x + np.float32(a.bloom) * glow
        y = 1.0 - cv2.exp(-x)  # filmic shoulder: highlights saturate smoothly
        y = cv2.pow(np.maximum(y, 0.0), 1.0 / 2.2)
        grey = y @ np.array([0.299, 0.587, 0.114], np.float32)
        y = grey[..., None] + SATURATION_BOOST * (y - grey[..., None])  # camera colour processing
        y = cv2.GaussianBlur(y, (0, 0), 0.45 * max(1.0, w / 512.0))
        if a.grain > 0:
            g = np.float32(0.01 * a.grain)
            y = (y + g * rng.standard_normal((h, w, 1), dtype=np.float32)
                 + (0.4 * g) * rng.standard_normal((h, w, 3), dtype=np.float32))
        return np.clip(y * 255.0 + 0.5, 0, 255).astype(np.uint8)

    # ------------------------------------------------------------------ all together
    def render(self, T_wc: np.ndarray, rng: np.random.Generator, blur_poses: list[np.ndarray] | None = None,
               hits: Hits | None = None) -> tuple[np.ndarray, np.ndarray]:
        """RGB (H, W, 3) uint8 and depth (H, W) float32 metres of pose ``T_wc``.

        ``blur_poses`` (motion blur): extra poses inside the shutter interval whose
        radiance is averaged with that of ``T_wc``; depth is always that of ``T_wc``.
        ``hits``: the result of ``trace(T_wc)`` if already computed.
        """
        hits = self.trace(T_wc) if hits is None else hits
        radiance, lum = self.shade(hits, T_wc)
        if blur_poses:
            for T in blur_poses:
                r2, l2 = self.shade(self.trace(T), T)
                radiance += r2
                lum += l2
            k = np.float32(1.0 / (1 + len(blur_poses)))
            radiance *= k
            lum *= k
        return self.expose(radiance, lum, rng), hits.depth
