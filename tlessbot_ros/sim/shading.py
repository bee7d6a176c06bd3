"""Colour images of rendered scenes: Lambert + Blinn-Phong + ambient, translucency, cast shadows.

Inputs are per-pixel world-frame points and normals (from :class:`~tlessbot_ros.core.render.
RenderResult` and the analytic table plane z = 0); outputs are linear radiance images that
:func:`to_srgb8` turns into uint8 RGB with a display gamma. Reference: Blinn, "Models of light
reflection for computer synthesized pictures", SIGGRAPH 1977; wrap lighting for translucent
materials after GPU Gems ch. 16 (Green, 2004).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tlessbot_ros.core.common import CameraIntrinsics
from tlessbot_ros.sim.materials import Light, Material, Table


@dataclass
class Shaded:
    """Shading of N pixels: ``radiance`` (N, 3) float32 linear, ``highlight`` (N,) in [0, 1]."""

    radiance: np.ndarray
    highlight: np.ndarray


_RAY_CACHE: dict[tuple, np.ndarray] = {}


def camera_rays(intrinsics: CameraIntrinsics) -> np.ndarray:
    """(H, W, 3) float32 rays in the optical frame with z = 1 (so depth * ray = point)."""
    key = (intrinsics.width, intrinsics.height, *np.asarray(intrinsics.K).ravel())
    rays = _RAY_CACHE.get(key)
    if rays is None:
        u, v = np.meshgrid(np.arange(intrinsics.width, dtype=np.float64),
                           np.arange(intrinsics.height, dtype=np.float64))
        rays = np.stack([(u - intrinsics.cx) / intrinsics.fx, (v - intrinsics.cy) / intrinsics.fy,
                         np.ones_like(u)], axis=-1).astype(np.float32)
        _RAY_CACHE[key] = rays
    return rays


def table_depth(intrinsics: CameraIntrinsics, T_world_camera: np.ndarray) -> np.ndarray:
    """(H, W) float32 z-depth of the table plane z = 0 seen by the camera, 0 where not seen."""
    rays_c = camera_rays(intrinsics)
    R, t = T_world_camera[:3, :3], T_world_camera[:3, 3]
    dz = rays_c @ R[2].astype(np.float32)  # world z component of each ray (z_c = 1)
    with np.errstate(divide='ignore', invalid='ignore'):
        depth = np.where(dz < -1e-9, -t[2] / dz, 0.0)
    return depth.astype(np.float32)


def pixels_to_world(depth_m: np.ndarray, intrinsics: CameraIntrinsics,
                    T_world_camera: np.ndarray) -> np.ndarray:
    """(H, W, 3) float32 world points of a depth image (undefined where depth is 0)."""
    p_c = camera_rays(intrinsics) * depth_m[..., None]
    R, t = T_world_camera[:3, :3], T_world_camera[:3, 3]
    return (p_c @ R.T.astype(np.float32) + t.astype(np.float32)).astype(np.float32)


def blinn_phong(points_w: np.ndarray, normals_w: np.ndarray, eye_w: np.ndarray,
                albedo: np.ndarray, specular: np.ndarray, shininess: np.ndarray, light: Light,
                *, lit: np.ndarray | None = None,
                translucency: np.ndarray | None = None) -> Shaded:
    """Shade N surface points.

    Args:
        points_w: (N, 3) surface points, world frame, metres.
        normals_w: (N, 3) unit normals facing the viewer.
        eye_w: (3,) camera centre.
        albedo: (N, 3) linear diffuse reflectance.
        specular, shininess: (N,) Blinn-Phong coefficients.
        light: the point light and ambient level.
        lit: (N,) in [0, 1], 1 = the light reaches the point (cast shadows), None = all lit.
        translucency: (N,) in [0, 1]: wrap lighting ``(n.l + w) / (1 + w)`` and a glow.

    Returns:
        :class:`Shaded` with linear radiance (N, 3) and the specular highlight strength (N,).
    """
    light_pos = np.asarray(light.position_w, dtype=np.float32)
    colour = np.asarray(light.colour, dtype=np.float32) * np.float32(light.intensity)
    to_light = light_pos - points_w
    dist2 = np.maximum(np.sum(to_light * to_light, axis=1), 1e-6)
    to_light /= np.sqrt(dist2)[:, None]
    falloff = float(np.dot(light_pos, light_pos)) / dist2  # 1 at the table origin
    to_eye = eye_w.astype(np.float32) - points_w
    to_eye /= np.maximum(np.linalg.norm(to_eye, axis=1, keepdims=True), 1e-9)
    ndotl = np.sum(normals_w * to_light, axis=1)
    if translucency is not None:
        w = translucency.astype(np.float32)
        diffuse = np.clip((ndotl + w) / (1.0 + w), 0.0, None)
    else:
        diffuse = np.clip(ndotl, 0.0, None)
    half = to_light + to_eye
    half /= np.maximum(np.linalg.norm(half, axis=1, keepdims=True), 1e-9)
    ndoth = np.clip(np.sum(normals_w * half, axis=1), 0.0, 1.0)
    highlight = np.where(ndotl > 0, ndoth ** shininess, 0.0).astype(np.float32)
    shadow = np.ones_like(diffuse) if lit is None else lit.astype(np.float32)
    direct = (shadow * falloff)[:, None] * colour[None, :]
    radiance = (albedo * (diffuse[:, None] * direct + np.float32(light.ambient))
                + (specular * highlight)[:, None] * direct)
    if translucency is not None:
        # Light scattered inside the part: a soft glow independent of the normal.
        radiance += (0.25 * translucency * falloff)[:, None] * albedo * colour[None, :]
    return Shaded(radiance.astype(np.float32), (highlight * shadow).astype(np.float32))


def cast_shadows(scene, points_w: np.ndarray, normals_w: np.ndarray, light: Light,
                 *, offset_m: float = 5e-4) -> np.ndarray:
    """(N,) float32 1 where the light reaches the point, 0 in shadow (ray cast toward the light).

    ``scene`` is an ``open3d.t.geometry.RaycastingScene`` holding the occluders.
    """
    import open3d as o3d

    if len(points_w) == 0:
        return np.ones(0, np.float32)
    origins = points_w + offset_m * normals_w
    rays = np.empty((len(points_w), 6), np.float32)
    rays[:, :3] = origins
    rays[:, 3:] = np.asarray(light.position_w, np.float32) - origins
    occluded = scene.test_occlusions(o3d.core.Tensor(rays), tnear=0.0, tfar=1.0, nthreads=0)
    return 1.0 - occluded.numpy().astype(np.float32)


def shade_table(table: Table, points_w: np.ndarray, eye_w: np.ndarray, light: Light,
                *, lit: np.ndarray | None = None) -> Shaded:
    """Shade N points (N, 3) of the table plane (normal +z)."""
    n = len(points_w)
    albedo = table.albedo_at(points_w[:, :2])
    normals = np.zeros((n, 3), np.float32)
    normals[:, 2] = 1.0
    return blinn_phong(points_w, normals, eye_w, albedo, np.full(n, table.specular, np.float32),
                       np.full(n, table.shininess, np.float32), light, lit=lit)


def table_geometry(intrinsics: CameraIntrinsics, T_world_camera: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Table depth (H, W) float32 (0 = not seen) and table xy (H, W, 2) float32 per pixel."""
    depth = table_depth(intrinsics, T_world_camera)
    R = T_world_camera[:3, :3].astype(np.float32)
    xy = (camera_rays(intrinsics) @ R[:2].T) * depth[..., None]
    xy += T_world_camera[:2, 3].astype(np.float32)
    return depth, xy


def shade_table_image(table: Table, intrinsics: CameraIntrinsics, T_world_camera: np.ndarray,
                      light: Light, *, step_px: int = 4,
                      geometry: tuple[np.ndarray, np.ndarray] | None = None
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unshadowed table radiance (H, W, 3) float32, table depth (H, W) and table xy (H, W, 2).

    The lighting of a plane by a point light is smooth, so it is computed every ``step_px``
    pixels and interpolated; only the albedo texture is sampled at every pixel. ``geometry``
    is :func:`table_geometry` of this camera, if already computed.
    """
    import cv2

    h, w = intrinsics.height, intrinsics.width
    depth, xy = geometry if geometry is not None else table_geometry(intrinsics, T_world_camera)
    t = T_world_camera[:3, 3].astype(np.float32)
    ys = np.arange(0, h + step_px, step_px).clip(max=h - 1)
    xs = np.arange(0, w + step_px, step_px).clip(max=w - 1)
    grid = np.ix_(ys, xs)
    coarse = np.concatenate([xy[grid], np.zeros(xy[grid].shape[:2] + (1,), np.float32)],
                            axis=-1).reshape(-1, 3)
    n = len(coarse)
    normals = np.zeros((n, 3), np.float32)
    normals[:, 2] = 1.0
    white = blinn_phong(coarse, normals, t, np.ones((n, 3), np.float32), np.zeros(n, np.float32),
                        np.full(n, table.shininess, np.float32), light)
    spec = blinn_phong(coarse, normals, t, np.zeros((n, 3), np.float32),
                       np.full(n, table.specular, np.float32),
                       np.full(n, table.shininess, np.float32), light)
    gy, gx = len(ys), len(xs)
    # Resize so that coarse sample i lands on pixel ys[i] / xs[i] (grid spacing = step_px).
    size = ((gx - 1) * step_px + 1, (gy - 1) * step_px + 1)
    diffuse = cv2.resize(white.radiance.reshape(gy, gx, 3), size,
                         interpolation=cv2.INTER_LINEAR)[:h, :w]
    specular = cv2.resize(spec.radiance.reshape(gy, gx, 3), size,
                          interpolation=cv2.INTER_LINEAR)[:h, :w]
    radiance = table.albedo_at(xy)
    radiance *= diffuse
    radiance += specular
    radiance[depth <= 0] = 0.0
    return radiance, depth, xy


def material_arrays(materials: list[Material], instance: np.ndarray,
                    albedo_scale: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """Per-pixel material properties for pixels whose (N,) instance index is >= 0."""
    albedo = np.array([m.albedo for m in materials], np.float32).reshape(-1, 3)
    if albedo_scale is not None:
        albedo = albedo * np.asarray(albedo_scale, np.float32).reshape(-1, 1)
    return {
        'albedo': albedo[instance],
        'specular': np.array([m.specular for m in materials], np.float32)[instance],
        'shininess': np.array([m.shininess for m in materials], np.float32)[instance],
        'translucency': np.array([m.translucency for m in materials], np.float32)[instance],
        'ir_dropout': np.array([m.ir_dropout for m in materials], np.float32)[instance],
    }


def shade_render(result, T_world_camera: np.ndarray, materials: list[Material], light: Light,
                 *, background: np.ndarray | None = None, exposure: float = 1.0,
                 albedo_scale: np.ndarray | None = None, scene=None) -> np.ndarray:
    """Colour image of a :class:`~tlessbot_ros.core.common.RenderResult`.

    Args:
        result: the render (depth, instance, normals_c, ray_dirs_c) of a camera at
            ``T_world_camera`` (4x4, optical frame -> world).
        materials: one :class:`Material` per mesh index of the render.
        light: lamp and ambient (world frame).
        background: (H, W, 3) float32 linear radiance behind the meshes (what translucent parts
            let through), or None for black.
        exposure: radiance scale before the display gamma.
        albedo_scale: (len(materials),) per-mesh brightness factors, or None.
        scene: an ``open3d.t.geometry.RaycastingScene`` of the occluders (world frame) for cast
            shadows on the meshes, or None for no shadows.

    Returns:
        (H, W, 3) uint8 RGB (display gamma 1/2.2).
    """
    h, w = result.depth_m.shape
    radiance = (np.zeros((h, w, 3), np.float32) if background is None
                else np.array(background, dtype=np.float32, copy=True))
    part = result.instance >= 0
    if part.any():
        rows, cols = np.nonzero(part)
        R = np.asarray(T_world_camera[:3, :3], np.float32)
        eye = np.asarray(T_world_camera[:3, 3], np.float32)
        rays = result.ray_dirs_c[rows, cols]
        # ray_dirs_c are unit rays: the point is at depth / cos(angle to the optical axis).
        pts_c = rays * (result.depth_m[rows, cols] / rays[:, 2])[:, None]
        pts_w = pts_c @ R.T + eye
        n_w = result.normals_c[rows, cols] @ R.T
        mats = material_arrays(materials, result.instance[rows, cols], albedo_scale)
        lit = cast_shadows(scene, pts_w, n_w, light) if scene is not None else None
        shaded = blinn_phong(pts_w, n_w, eye, mats['albedo'], mats['specular'],
                             mats['shininess'], light, lit=lit,
                             translucency=mats['translucency'])
        tint = mats['albedo'] / np.maximum(mats['albedo'].max(axis=1, keepdims=True), 1e-6)
        bleed = (0.4 * mats['translucency'])[:, None]
        radiance[rows, cols] = ((1.0 - bleed) * shaded.radiance
                                + bleed * radiance[rows, cols] * tint)
    return to_srgb8(radiance, exposure)


_GAMMA_LUT = np.rint(255.0 * np.linspace(0.0, 1.0, 4096) ** (1.0 / 2.2)).astype(np.uint8)


def to_srgb8(radiance: np.ndarray, exposure: float = 1.0) -> np.ndarray:
    """Linear radiance (..., 3) -> uint8 with a 1/2.2 display gamma (clipped highlights).

    Uses a 4096-entry table (12-bit linear input, finer than one display step everywhere but in
    the deepest shadows)."""
    index = np.clip(radiance * np.float32(4095.0 * exposure), 0.0, 4095.0)
    return _GAMMA_LUT[(index + 0.5).astype(np.uint16)]
