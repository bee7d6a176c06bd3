"""Half turns and yaws of a flat part, its mesh's ray-casting scene, and a turned pose refitted
to the depth (for :class:`~tlessbot_ros.core.pose.flat.FlatCheck`).

Poses are ``T_camera_object`` (4, 4) float64, metres, optical frame; turns (4, 4) in the
model frame (applied on the right of a pose).
"""
from __future__ import annotations

from typing import TYPE_CHECKING, cast

import cv2
import numpy as np

from tlessbot_ros.core.common import invert_transform, rotation_about_axis, transform_points

if TYPE_CHECKING:
    from collections.abc import Sequence

    import open3d as o3d
    from scipy.spatial import cKDTree

    from tlessbot_ros.core.pose.database import ObjectTemplates
    from tlessbot_ros.core.pose.flat import FlatCheck, ViewEvidence


def principal_half_turns(vertices: np.ndarray) -> list[np.ndarray]:
    """The (4, 4) half turns (model frame) about the three principal axes of a mesh's
    vertices (or surface samples), through the centre of their principal-axis box."""
    v = np.asarray(vertices, np.float64)
    mean = v.mean(axis=0)
    axes = np.linalg.svd(v - mean, full_matrices=False)[2]
    coords = (v - mean) @ axes.T
    centre = mean + ((coords.max(axis=0) + coords.min(axis=0)) / 2.0) @ axes
    turns = []
    for axis in axes:
        T = np.eye(4)
        T[:3, :3] = rotation_about_axis(axis, np.pi)
        T[:3, 3] = centre - T[:3, :3] @ centre
        turns.append(T)
    return turns


def outline_half_turns(points_o: np.ndarray) -> list[np.ndarray]:
    """The (4, 4) half turns (model frame) of a flat part about the axes of its outline's
    smallest enclosing rectangle (seen along its thinnest principal axis; OpenCV's
    ``minAreaRect``, Freeman & Shapira 1975) and about that thin axis, all through the centre
    of that rectangle at mid-thickness. Unlike the principal axes of its surface, which holes
    placed off the middle tilt by a degree or two, these are the axes a rectangular, round or
    otherwise symmetric outline is symmetric about: turned about them, such an outline covers
    the same pixels and the turned poses differ only where the holes and cut corners do."""
    centre, first, second, thin, _ = outline_frame(points_o)
    return [turn_about(axis, np.pi, centre) for axis in (first, second, thin)]


# an outline is round when its convex hull covers this share of the circle through its
# farthest point (a disc 1, a square 2/π)
ROUND_SHARE = 0.95


def outline_yaws(points_o: np.ndarray, period_rad: float, steps: int, *,
                 roundness: float = ROUND_SHARE) -> list[np.ndarray]:
    """For a flat part with a round outline (its convex hull covers at least ``roundness`` of
    the circle about the outline's centre through its farthest point): the (4, 4) turns about
    its thin axis through the outline's centre by k / ``steps`` of ``period_rad`` (its yaw
    period on the table, 2π for none), k = 1 .. steps - 1; none for another outline or a
    continuous symmetry (period 0).
    A round outline holds no yaw, for the depth or the outline alike: only the holes do."""
    centre, _, _, thin, round_share = outline_frame(points_o)
    if period_rad <= 0 or steps < 2 or round_share < roundness:
        return []
    return [turn_about(thin, k * period_rad / steps, centre) for k in range(1, steps)]


def outline_frame(points_o: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, float]:
    """A flat part's outline seen along its thinnest principal axis: (the centre of its
    smallest enclosing rectangle at mid-thickness (3,), the rectangle's two axes (3,) each, the
    thin axis (3,), the share of the circle about that centre through the outline's farthest
    point that its convex hull covers: 1 for a disc, 2/π at most for a rectangle)."""
    points = np.asarray(points_o, np.float64)
    mean = points.mean(axis=0)
    axes = np.linalg.svd(points - mean, full_matrices=False)[2]
    thin = axes[2]
    u, v = axes[0], np.cross(thin, axes[0])
    plane = (1e3 * np.stack([(points - mean) @ u, (points - mean) @ v], axis=1)).astype(
        np.float32)
    (cx, cy), _, angle = cv2.minAreaRect(plane)
    a = np.radians(angle)
    first = np.cos(a) * u + np.sin(a) * v
    depth = (points - mean) @ thin
    centre = mean + 1e-3 * (cx * u + cy * v) + (depth.max() + depth.min()) / 2.0 * thin
    hull = cv2.convexHull(plane).reshape(-1, 2)
    radius = float(np.hypot(hull[:, 0] - cx, hull[:, 1] - cy).max())
    round_share = float(cv2.contourArea(hull)) / (np.pi * radius ** 2) if radius > 0 else 0.0
    return centre, first, np.cross(thin, first), thin, round_share


def turn_about(axis: np.ndarray, angle: float, centre: np.ndarray) -> np.ndarray:
    """(4, 4) rotation by ``angle`` about ``axis`` through the point ``centre``."""
    T = np.eye(4)
    T[:3, :3] = rotation_about_axis(axis, angle)
    T[:3, 3] = centre - T[:3, :3] @ centre
    return T


def mesh_scene(obj: ObjectTemplates) -> o3d.t.geometry.RaycastingScene | None:
    """The ray-casting scene of the object's mesh in its model frame (cached on the object;
    None without a mesh)."""
    from tlessbot_ros.core.common import raycasting_scene

    vertices, faces = obj.mesh_vertices, obj.mesh_faces
    if faces is None or vertices is None:
        return None
    scene: o3d.t.geometry.RaycastingScene = obj.derived(
        'raycasting', lambda: raycasting_scene(vertices, faces))
    return scene


def refine_yaw(check: FlatCheck, obj: ObjectTemplates, T_camera_object: np.ndarray,
               T_world_camera: np.ndarray, views: Sequence[ViewEvidence]
               ) -> tuple[np.ndarray, float]:
    """A flat part's pose turned about the vertical through its centre by the yaw among
    ``yaw_steps`` steps of ``yaw_step_deg`` either way whose silhouette agrees best with the
    image (:func:`agreement`); the fitted pose unless that gains more than ``yaw_min_gain``.
    The depth of a part a few millimetres thin holds its yaw only by its few edge points; its
    outline in the image holds it better (docs/bench/flat-parts.md). Returns the pose
    and the yaw (degrees) it was turned by."""
    p = check.params
    T_camera_object = np.asarray(T_camera_object, np.float64)
    if p.yaw_steps < 1:
        return T_camera_object, 0.0
    yaws = p.yaw_step_deg * np.arange(-p.yaw_steps, p.yaw_steps + 1)
    centre = bbox_centre(obj)
    T_world = np.asarray(T_world_camera, np.float64)
    T_world_object = T_world @ T_camera_object
    c = transform_points(T_world_object, centre[None])[0]
    poses = []
    for yaw in np.radians(yaws):
        R = rotation_about_axis(np.array([0.0, 0.0, 1.0]), yaw)
        T = T_world_object.copy()
        T[:3, :3] = R @ T[:3, :3]
        T[:3, 3] = R @ (T[:3, 3] - c) + c
        poses.append(invert_transform(T_world) @ T)
    scores, _, _ = check.image_evidence(obj, poses, views)
    k = int(np.argmax(scores))
    if scores[k] > scores[p.yaw_steps] + p.yaw_min_gain:
        return poses[k], float(yaws[k])
    return T_camera_object, 0.0


def bbox_centre(obj: ObjectTemplates) -> np.ndarray:
    """(3,) the centre of the object's bounding box, object frame (cached on the object)."""
    return cast(np.ndarray, obj.derived('bbox_centre', lambda: (
        obj.model_points.min(axis=0) + obj.model_points.max(axis=0)).astype(np.float64) / 2))


def refit_to_surface(obj: ObjectTemplates, T_camera_object: np.ndarray,
                     points_c: np.ndarray) -> np.ndarray:
    """``T_camera_object`` refined by point-to-plane ICP (:func:`point_to_plane_icp`) of the
    ROI cloud onto 3000 samples of the mesh's surface, within 3 mm, at most 20 iterations."""
    from scipy.spatial import cKDTree

    from tlessbot_ros.core.common import sample_surface

    vertices, faces = obj.mesh_vertices, obj.mesh_faces
    assert vertices is not None and faces is not None

    def surface() -> tuple[cKDTree, np.ndarray]:
        points, normals = sample_surface(vertices, faces, 3000, seed=0)
        return cKDTree(np.asarray(points, np.float64)), np.asarray(normals, np.float64)

    tree, normals = obj.derived('surface_tree', surface)
    T_inv = invert_transform(np.asarray(T_camera_object, np.float64))
    source = transform_points(T_inv, np.asarray(points_c, np.float64))
    update = point_to_plane_icp(source, tree, normals, 0.003, 20)
    return np.asarray(T_camera_object @ invert_transform(update))


def point_to_plane_icp(source: np.ndarray, target: cKDTree, target_normals: np.ndarray,
                       max_distance_m: float, iterations: int, *,
                       relative_change: float = 1e-6) -> np.ndarray:
    """(4, 4) transform that moves ``source`` (N, 3) onto the surface sampled by ``target``
    (a KD-tree of (M, 3) points with unit normals ``target_normals``), by point-to-plane ICP
    (Chen & Medioni 1992) with the nearest sample within ``max_distance_m`` as correspondence.

    Each step solves the linearised 6-DOF least squares (rotation as small x-y-z angles) and
    stops when neither the inlier share nor the inlier RMSE changes by ``relative_change``;
    the criteria of Open3D's ``registration_icp``, whose parallel sums make its last bits vary
    from run to run. Sums here are in a fixed order, so the same input gives the same pose.
    """
    T = np.eye(4)
    moved = np.asarray(source, np.float64)
    if len(moved) == 0:
        return T
    previous = None
    for _ in range(iterations):
        distance, index = target.query(moved, distance_upper_bound=max_distance_m)
        near = np.isfinite(distance)
        if not near.any():
            break
        share = float(near.mean())
        rmse = float(np.sqrt(np.mean(distance[near] ** 2)))
        if previous is not None and abs(previous[0] - share) < relative_change and \
                abs(previous[1] - rmse) < relative_change:
            break
        previous = (share, rmse)
        step = _point_to_plane_step(moved[near], target.data[index[near]],
                                    target_normals[index[near]])
        if step is None:
            break
        moved = transform_points(step, moved)
        T = step @ T
    return T


def _point_to_plane_step(source: np.ndarray, target: np.ndarray, normals: np.ndarray
                         ) -> np.ndarray | None:
    """(4, 4) the linearised least-squares step of point-to-plane ICP over correspondences
    (N, 3) each, or None when the 6x6 system is singular."""
    residual = np.einsum('ij,ij->i', source - target, normals)
    J = np.hstack([np.cross(source, normals), normals])
    try:
        x = np.linalg.solve(J.T @ J, -J.T @ residual)
    except np.linalg.LinAlgError:
        return None
    step = np.eye(4)
    step[:3, :3] = (rotation_about_axis(np.array([0.0, 0.0, 1.0]), x[2])
                    @ rotation_about_axis(np.array([0.0, 1.0, 0.0]), x[1])
                    @ rotation_about_axis(np.array([1.0, 0.0, 0.0]), x[0]))
    step[:3, 3] = x[3:]
    return step


def level_on_table(T_camera_object: np.ndarray, points_o: np.ndarray, normal_c: np.ndarray,
                   tolerance_m: float) -> np.ndarray | None:
    """A flat part's pose turned, about its outline's centre, by the least rotation that lays
    its thin axis along the table's normal ``normal_c`` (camera frame; lying on a face) or
    square to it (standing on an edge), whichever is nearer; None when that moves a model
    sample (``points_o``) by more than ``tolerance_m`` (the part leans, or the fit is off by
    more than the depth's resolution) or by nothing.

    Resting on the table, a flat part's face is level or upright. The depth of a strip 16 mm
    wide holds its roll about its long axis only to about atan(noise / half-width) (2 mm over
    8 mm: 14 degrees), so the fit leaves it a few degrees off; a turn that moves no sample by
    more than the depth resolves is not measured, and the table decides it."""
    T = np.asarray(T_camera_object, np.float64)
    centre_o, _, _, thin_o, _ = outline_frame(points_o)
    normal = np.asarray(normal_c, np.float64) / np.linalg.norm(normal_c)
    thin = T[:3, :3] @ thin_o
    along = float(thin @ normal)
    target = normal * np.sign(along) if abs(along) >= np.sqrt(0.5) \
        else thin - along * normal
    target /= np.linalg.norm(target)
    axis = np.cross(thin, target)
    angle = float(np.arctan2(np.linalg.norm(axis), thin @ target))
    if angle <= 0.0 or np.linalg.norm(axis) == 0.0:
        return None
    R = rotation_about_axis(axis / np.linalg.norm(axis), angle)
    centre = T[:3, :3] @ centre_o + T[:3, 3]
    out = np.eye(4)
    out[:3, :3] = R @ T[:3, :3]
    out[:3, 3] = centre + R @ (T[:3, 3] - centre)
    moved = np.linalg.norm(transform_points(out, points_o) - transform_points(T, points_o),
                           axis=1)
    return out if float(moved.max()) <= tolerance_m else None


__all__ = ['ROUND_SHARE', 'bbox_centre', 'level_on_table', 'mesh_scene', 'outline_frame',
           'outline_half_turns', 'outline_yaws', 'principal_half_turns', 'refine_yaw',
           'refit_to_surface', 'turn_about']
