"""The placed parts of a simulated frame as ray-casting targets (Open3D ``RaycastingScene``).

One scene per model, cached on the model; rays are moved into each part's frame and cast only
where they pass within the part's bounding sphere. Same conventions as
:mod:`tlessbot_ros.core.common.render`: camera rays have z = 1 in the optical frame, so a hit's
ray parameter is its depth.
"""
from __future__ import annotations

import numpy as np

from tlessbot_ros.core.common import CameraMount, project_points, transform_points
from tlessbot_ros.io.models import ObjectModel
from tlessbot_ros.sim.materials import Light
from tlessbot_ros.sim.scene import PlacedObject


def model_scene(model: ObjectModel):
    """Open3D ray-casting scene of one model in its own frame, cached on the model (its BVH is
    built once, not per frame)."""
    def build():
        import open3d as o3d

        scene = o3d.t.geometry.RaycastingScene()
        mesh = o3d.t.geometry.TriangleMesh()
        mesh.vertex.positions = o3d.core.Tensor(np.ascontiguousarray(model.vertices, np.float32))
        mesh.triangle.indices = o3d.core.Tensor(np.ascontiguousarray(model.faces, np.int32))
        scene.add_triangles(mesh)
        return scene
    return model.cached('o3d_scene', build)


class PlacedParts:
    """The placed parts as ray-casting targets: rays are moved into each part's frame and cast
    against the model's cached scene (rigid motions keep the ray parameter t), only for rays
    that pass within the part's bounding sphere."""

    def __init__(self, models: dict[int, ObjectModel], objects: list[PlacedObject]) -> None:
        self.items = []
        for obj in objects:
            model = models[obj.obj_id]
            T = np.asarray(obj.T_world_object, np.float64)
            radius = float(np.linalg.norm(model.vertices, axis=1).max())
            self.items.append((model_scene(model), T[:3, :3].astype(np.float32),
                               T[:3, 3].astype(np.float32), radius))

    def __len__(self) -> int:
        return len(self.items)

    @staticmethod
    def _near(origins: np.ndarray, dirs: np.ndarray, centre: np.ndarray, radius: float,
              tfar: float | None = None) -> np.ndarray:
        """Rays (or segments up to ``tfar``) that come within ``radius`` of ``centre``."""
        oc = centre - origins
        dd = np.einsum('ij,ij->i', dirs, dirs)
        t = np.einsum('ij,ij->i', oc, dirs) / dd
        t = np.clip(t, 0.0, tfar) if tfar is not None else np.maximum(t, 0.0)
        closest = origins + t[:, None] * dirs - centre
        return np.einsum('ij,ij->i', closest, closest) <= (radius * 1.01 + 1e-4) ** 2

    def _local(self, k: int, origins: np.ndarray, dirs: np.ndarray):
        import open3d as o3d

        _, R, t, _ = self.items[k]
        rays = np.empty((len(origins), 6), np.float32)
        rays[:, :3] = (origins - t) @ R  # R^T (o - t), row-vector form
        rays[:, 3:] = dirs @ R
        return o3d.core.Tensor(rays)

    def cast(self, origins: np.ndarray, dirs: np.ndarray
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """First hits of N rays: t (N,) (inf = none), part index (N,) (-1), world normals."""
        n = len(origins)
        best = np.full(n, np.inf, np.float32)
        index = np.full(n, -1, np.int32)
        normals = np.zeros((n, 3), np.float32)
        for k, (scene, R, t, radius) in enumerate(self.items):
            sel = np.flatnonzero(self._near(origins, dirs, t, radius))
            if len(sel) == 0:
                continue
            hits = scene.cast_rays(self._local(k, origins[sel], dirs[sel]))
            t_hit = hits['t_hit'].numpy()
            closer = t_hit < best[sel]
            idx = sel[closer]
            best[idx] = t_hit[closer]
            index[idx] = k
            normals[idx] = hits['primitive_normals'].numpy()[closer] @ R.T
        return best, index, normals

    def hits(self, k: int, origins: np.ndarray, dirs: np.ndarray) -> np.ndarray:
        """(N,) bool: rays that meet part ``k`` (ignoring the others)."""
        scene, _, t, radius = self.items[k]
        out = np.zeros(len(origins), bool)
        sel = np.flatnonzero(self._near(origins, dirs, t, radius))
        if len(sel):
            t_hit = scene.cast_rays(self._local(k, origins[sel], dirs[sel]))['t_hit'].numpy()
            out[sel] = np.isfinite(t_hit)
        return out

    def occluded(self, origins: np.ndarray, vectors: np.ndarray) -> np.ndarray:
        """(N,) bool: segments ``origins -> origins + vectors`` blocked by any part."""
        out = np.zeros(len(origins), bool)
        for k, (scene, _, t, radius) in enumerate(self.items):
            sel = np.flatnonzero(~out & self._near(origins, vectors, t, radius, tfar=1.0))
            if len(sel):
                blocked = scene.test_occlusions(self._local(k, origins[sel], vectors[sel]),
                                                tnear=0.0, tfar=1.0).numpy()
                out[sel[blocked]] = True
        return out


def cast_view(parts: PlacedParts, rays_c: np.ndarray, T_world_camera: np.ndarray,
               roi: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Cast a camera's rays (z = 1 in the optical frame) inside ``roi`` (H, W) bool: depth
    (H, W) float32 (0 = no part), instance (H, W) int32 (-1 = none) and world normals
    (H, W, 3) float32 (unoriented, zero where no part)."""
    h, w = rays_c.shape[:2]
    R = T_world_camera[:3, :3].astype(np.float32)
    rows, cols = np.nonzero(roi)
    dirs = rays_c[rows, cols] @ R.T
    origins = np.broadcast_to(T_world_camera[:3, 3].astype(np.float32), dirs.shape)
    t_hit, index, normals_hit = parts.cast(origins, dirs)
    hit = index >= 0
    depth = np.zeros((h, w), np.float32)
    instance = np.full((h, w), -1, np.int32)
    normals = np.zeros((h, w, 3), np.float32)
    r, c = rows[hit], cols[hit]
    depth[r, c] = t_hit[hit]  # z = 1 rays: t is the depth
    instance[r, c] = index[hit]
    normals[r, c] = normals_hit[hit]
    return depth, instance, normals


def parts_roi(meshes_w: list, cam: CameraMount) -> np.ndarray:
    """(H, W) bool union of the parts' projected bounding boxes (where rays can hit a part)."""
    intr = cam.intrinsics
    roi = np.zeros((intr.height, intr.width), bool)
    for vertices, _ in meshes_w:
        pts_c = transform_points(cam.T_camera_world, vertices)
        if np.any(pts_c[:, 2] <= 1e-3):  # reaches behind the camera: cast everything
            roi[:] = True
            return roi
        uv = project_points(pts_c, intr.K)
        x0, y0 = np.floor(uv.min(axis=0)).astype(int) - 1
        x1, y1 = np.ceil(uv.max(axis=0)).astype(int) + 1
        roi[max(y0, 0):max(y1 + 1, 0), max(x0, 0):max(x1 + 1, 0)] = True
    return roi


def lit_by_lamp(parts: PlacedParts, points_w: np.ndarray, normals_w: np.ndarray, light: Light,
         offset_m: float = 5e-4) -> np.ndarray:
    """(N,) float32 1 where the lamp reaches the point, 0 where a part casts a shadow."""
    origins = points_w + np.float32(offset_m) * normals_w
    vectors = np.asarray(light.position_w, np.float32) - origins
    return 1.0 - parts.occluded(origins, vectors).astype(np.float32)
