"""Flat parts turned over: tell a flat part from its mirror image by what the depth shows.

A plate 4 mm thick fits the depth of its upper face as well upside down (turned 180° about an
axis in its plane) as the right way up: the fit cannot tell them apart, and nor can ADD-S.
What differs is where its holes, slots and outline features lie. :class:`FlipCheck` ray-casts
the part's mesh at the fitted pose and at each half turn about the principal axes of the part
(through the centre of its bounding box, along those axes) along the pixel rays of the part's
ROI clouds; the pose whose surface explains more pixels by a clear margin (the depth vote of
:mod:`~tlessbot_ros.core.pose.lookalike`: a pixel the mesh misses, where a hole is, counts as
a gross error) is kept. A turn that maps the part onto itself (a symmetry) wins no pixels.
"""
from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import cast

import numpy as np
import open3d as o3d

from tlessbot_ros.core.common import rotation_about_axis, sample_surface
from tlessbot_ros.core.pose.lookalike import Mesh, MeshScenes, depth_errors, pooled_vote

# A part is flat when its thinnest principal extent is at most this share of its middle one.
FLAT_RATIO = 0.3


def half_turns(vertices: np.ndarray, *, flat_ratio: float = FLAT_RATIO) -> list[np.ndarray]:
    """The 4x4 half turns (model frame, metres) about the three principal axes of a flat part,
    through the centre of its principal-axis bounding box; [] for a part that is not flat.

    Args:
        vertices: (V, 3) model vertices, metres.
    """
    v = np.asarray(vertices, np.float64)
    mean = v.mean(axis=0)
    axes = np.linalg.svd(v - mean, full_matrices=False)[2]   # rows: principal axes
    coords = (v - mean) @ axes.T
    extent = np.sort(np.ptp(coords, axis=0))
    if extent[0] > flat_ratio * extent[1]:
        return []
    centre = mean + ((coords.max(axis=0) + coords.min(axis=0)) / 2.0) @ axes
    turns = []
    for axis in axes:
        T = np.eye(4)
        T[:3, :3] = rotation_about_axis(axis, np.pi)
        T[:3, 3] = centre - T[:3, :3] @ centre
        turns.append(T)
    return turns


class FlipCheck:
    """Turns a fitted flat part over when the depth shows it lies the other way up.

    Args:
        meshes: {obj_id: (vertices m, faces)} of the parts to check (flat ones are kept).
        tolerance_m, min_z: the depth vote's (:func:`~.lookalike.depth_vote`,
            :func:`~.lookalike.clear_margin`).
    """

    def __init__(self, meshes: Mapping[int, Mesh], *, tolerance_m: float = 0.002,
                 min_z: float = 0.0) -> None:
        self.turns: dict[int, list[np.ndarray]] = {}
        for obj_id, (vertices, _) in meshes.items():
            turns = half_turns(vertices)
            if turns:
                self.turns[int(obj_id)] = turns
        self._scenes = MeshScenes({i: meshes[i] for i in self.turns})
        self._surfaces: dict[int, o3d.geometry.PointCloud] = {}
        self.tolerance_m, self.min_z = float(tolerance_m), float(min_z)

    def __contains__(self, obj_id: object) -> bool:
        return obj_id in self.turns

    def warm_up(self) -> None:
        """Build each part's ray-casting scene (and its BVH) now."""
        self._scenes.warm_up(self.turns)

    def resolve(self, obj_id: int, T_camera_object: np.ndarray, points_c: np.ndarray, *,
                more_views: Sequence[tuple[np.ndarray, np.ndarray]] = ()
                ) -> tuple[np.ndarray, float]:
        """(pose, its vote): ``T_camera_object`` itself (vote 0) unless a half turn of the part
        explains the depth of its views better by a clear margin.

        Args:
            obj_id: the part's class; T_camera_object: (4, 4) its fitted pose.
            points_c: (N, 3) ROI cloud, metres, optical frame; more_views: as
                :meth:`~.lookalike.LookalikeCheck.resolve`.
        """
        T0 = np.asarray(T_camera_object, np.float64)
        if int(obj_id) not in self.turns:
            return T0, 0.0
        scene = self._scenes[int(obj_id)]
        views = [(np.eye(4), points_c)] + [(np.asarray(T, np.float64), points)
                                           for points, T in more_views]
        views = [(T, points) for T, points in views if len(points)]
        if not views:
            return T0, 0.0
        own = [depth_errors(scene, T @ T0, points) for T, points in views]
        best, best_vote = T0, 0.0
        for turn in self.turns[int(obj_id)]:
            # the fit placed the wrong side's features over the right side's: the turned
            # pose is first refitted to the cloud, so that its features can line up
            turned = self._refit(int(obj_id), T0 @ turn, points_c)
            vote = pooled_vote([depth_errors(scene, T @ turned, points) for T, points in views],
                               own, self.tolerance_m, self.min_z)
            if vote > best_vote:
                best, best_vote = turned, vote
        return best, best_vote

    def _refit(self, obj_id: int, T_camera_object: np.ndarray, points_c: np.ndarray
               ) -> np.ndarray:
        """``T_camera_object`` refined by point-to-plane ICP of the cloud onto the model
        surface (Chen & Medioni 1992; Open3D), within 3 mm, at most 20 iterations."""
        if obj_id not in self._surfaces:
            points, normals = sample_surface(*self._scenes.meshes[obj_id], 3000, seed=0)
            target = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
            target.normals = o3d.utility.Vector3dVector(normals)
            self._surfaces[obj_id] = target
        T_inv = np.linalg.inv(T_camera_object)
        source = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(
            np.asarray(points_c, np.float64) @ T_inv[:3, :3].T + T_inv[:3, 3]))
        result = o3d.pipelines.registration.registration_icp(
            source, self._surfaces[obj_id], 0.003, np.eye(4),
            o3d.pipelines.registration.TransformationEstimationPointToPlane(),
            o3d.pipelines.registration.ICPConvergenceCriteria(max_iteration=20))
        return cast(np.ndarray, T_camera_object @ np.linalg.inv(result.transformation))
