"""Depth, instance and normal images of triangle meshes by ray casting (Open3D, CPU, headless).

Pixel centres are at integer coordinates, matching :func:`~tlessbot_ros.core.geometry.
depth_to_points`, so rendering a mesh and back-projecting its depth gives points on the surface.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import open3d as o3d

from tlessbot_ros.core.common.geometry import CameraIntrinsics, transform_points

NO_HIT = -1


def o3d_tensor(array: np.ndarray) -> o3d.core.Tensor:
    """An Open3D CPU tensor with a copy of ``array`` (same shape and dtype)."""
    # Open3D's stubs leave out the defaults of dtype and device, which the binding has.
    return o3d.core.Tensor(array)  # type: ignore[call-overload, no-any-return]


def raycasting_scene(vertices: np.ndarray, faces: np.ndarray) -> o3d.t.geometry.RaycastingScene:
    """An Open3D ray-casting scene of one mesh ((V, 3) vertices, metres; (F, 3) int faces) in
    its own frame: for rays, exact point distances and closest points."""
    mesh = o3d.t.geometry.TriangleMesh()
    mesh.vertex.positions = o3d_tensor(np.asarray(vertices, np.float32))
    mesh.triangle.indices = o3d_tensor(np.asarray(faces, np.int32))
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(mesh)
    return scene


@dataclass
class RenderResult:
    """One rendered view.

    Attributes:
        depth_m: (H, W) float32 depth along the optical axis in metres, 0 where no surface.
        instance: (H, W) int32 index of the visible mesh (order of ``add_mesh``), -1 = none.
        normals_c: (H, W, 3) float32 unit surface normals in the camera frame, facing the
            camera (n . ray <= 0); zero where no surface.
        ray_dirs_c: (H, W, 3) float32 unit viewing rays in the camera frame.
    """

    depth_m: np.ndarray
    instance: np.ndarray
    normals_c: np.ndarray
    ray_dirs_c: np.ndarray


class MeshRenderer:
    """A static set of meshes placed in a common (world) frame, rendered from any camera."""

    def __init__(self) -> None:
        self._scene = o3d.t.geometry.RaycastingScene()
        self._geometry_to_instance: dict[int, int] = {}
        self._count = 0
        self._ray_cache: dict[tuple[int | float, ...], np.ndarray] = {}

    def add_mesh(self, vertices: np.ndarray, faces: np.ndarray,
                 T_world_object: np.ndarray | None = None) -> int:
        """Add a mesh ((V, 3) vertices, metres; (F, 3) int faces) at a pose; returns its index."""
        vertices = np.asarray(vertices, dtype=np.float64)
        if T_world_object is not None:
            vertices = transform_points(T_world_object, vertices)
        mesh = o3d.t.geometry.TriangleMesh()
        mesh.vertex.positions = o3d_tensor(vertices.astype(np.float32))
        mesh.triangle.indices = o3d_tensor(np.asarray(faces, dtype=np.int32))
        geometry_id = self._scene.add_triangles(mesh)
        self._geometry_to_instance[int(geometry_id)] = self._count
        self._count += 1
        return self._count - 1

    def __len__(self) -> int:
        return self._count

    def _rays_c(self, intrinsics: CameraIntrinsics) -> np.ndarray:
        key = (intrinsics.width, intrinsics.height, *intrinsics.K.ravel())
        rays = self._ray_cache.get(key)
        if rays is None:
            u, v = np.meshgrid(np.arange(intrinsics.width), np.arange(intrinsics.height))
            rays = np.stack([(u - intrinsics.cx) / intrinsics.fx,
                             (v - intrinsics.cy) / intrinsics.fy,
                             np.ones(u.shape)], axis=-1)  # z = 1: t_hit is the depth
            self._ray_cache[key] = rays
        return rays

    def render(self, intrinsics: CameraIntrinsics, T_world_camera: np.ndarray) -> RenderResult:
        """Ray-cast every pixel of a pinhole camera at ``T_world_camera`` (optical frame)."""
        rays_c = self._rays_c(intrinsics)
        height, width = rays_c.shape[:2]
        R, t = T_world_camera[:3, :3], T_world_camera[:3, 3]
        rays = np.empty((height, width, 6), np.float32)
        rays[..., :3] = t
        rays[..., 3:] = rays_c @ R.T
        hits = self._scene.cast_rays(o3d_tensor(rays), nthreads=0)
        t_hit = hits['t_hit'].numpy()
        hit = np.isfinite(t_hit)
        depth = np.where(hit, t_hit, 0.0).astype(np.float32)
        geometry = hits['geometry_ids'].numpy().astype(np.int64)
        instance = np.full((height, width), NO_HIT, np.int32)
        lookup = np.full(max(self._geometry_to_instance, default=0) + 2, NO_HIT, np.int32)
        for geometry_id, index in self._geometry_to_instance.items():
            lookup[geometry_id] = index
        instance[hit] = lookup[np.minimum(geometry[hit], len(lookup) - 1)]
        normals_w = hits['primitive_normals'].numpy()
        normals_c = normals_w @ R  # world -> camera: R^T n, row-vector form
        unit_rays = (rays_c / np.linalg.norm(rays_c, axis=-1, keepdims=True)).astype(np.float32)
        facing = np.sum(normals_c * unit_rays, axis=-1, keepdims=True)
        normals_c = np.where(facing > 0, -normals_c, normals_c).astype(np.float32)
        normals_c[~hit] = 0.0
        return RenderResult(depth, instance, normals_c, unit_rays)
