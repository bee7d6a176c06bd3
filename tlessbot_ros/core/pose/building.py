"""Building the template database (paper §3.3, §6.2: 12 turntable views, 30° apart).

Each object gets N partial views (2–18, default 12) rendered from its CAD model as the side camera
sees it resting on the table in a stable pose, the table turned in yaw steps of 360°/N
(:func:`build_object_templates`, :func:`build_database`), or views captured from real turntable
clouds (:func:`template_from_cloud`). Per object it also finds the stable poses that show the
same resting shape (:func:`merge_equivalent_poses`), the yaw period of each stable pose
(:func:`yaw_period`) and the parts that look alike
(:func:`~tlessbot_ros.core.pose.lookalike_pairs`). What is stored, and how, is
:mod:`tlessbot_ros.core.pose.database`.
"""
from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping
from dataclasses import asdict, dataclass, field
from typing import Any, cast

import numpy as np

from tlessbot_ros.core.common import (
    CameraIntrinsics,
    Symmetries,
    depth_to_points,
    invert_transform,
    make_transform,
    o3d_tensor,
    point_set_diameter,
    raycasting_scene,
    rotation_about_axis,
    rotation_angle_deg,
    sample_surface,
    transform_points,
)
from tlessbot_ros.core.pose.cloud import CloudParams, compute_fpfh, preprocess_roi
from tlessbot_ros.core.pose.database import (
    CONTINUOUS_YAW_PERIOD,
    ObjectTemplates,
    Template,
    TemplateDatabase,
)
from tlessbot_ros.core.pose.flat_params import is_flat_mesh
from tlessbot_ros.core.pose.lookalike import lookalike_pairs

MIN_VIEWS, MAX_VIEWS = 2, 18


@dataclass(frozen=True)
class TemplateParams:
    """Template-building parameters.

    Attributes:
        n_views: turntable views per stable pose (paper: 12, 30° apart; 2–18 allowed).
        voxel_fraction: voxel edge as a fraction of the object diameter (algo-notes §C.3:
            diam/20–diam/30).
        fpfh_radius_voxels, fpfh_max_nn: FPFH support (algo-notes §C.3: 5 voxels, 100).
        max_stable_poses: templates are rendered for the most probable stable poses, up to this
            many (the paper's turntable shows the part in one pose).
        min_stable_probability: stable poses less likely than this are ignored.
        model_samples: surface samples per object for the fast path and ICP.
        seed: seed of the surface sampling.
        lookalike_min_shared, lookalike_tolerance_m: parts sharing at least this share of
            their surface within this distance are look-alikes
            (:func:`~tlessbot_ros.core.pose.lookalike_pairs`); their meshes are stored so
            the pose stage can tell them apart.
    """

    n_views: int = 12
    voxel_fraction: float = 1.0 / 25.0
    fpfh_radius_voxels: float = 5.0
    fpfh_max_nn: int = 100
    max_stable_poses: int = 1
    min_stable_probability: float = 0.02
    model_samples: int = 3000
    seed: int = 0
    lookalike_min_shared: float = 0.8
    lookalike_tolerance_m: float = 0.002
    cloud: CloudParams = field(default_factory=CloudParams)

    def __post_init__(self) -> None:
        if not MIN_VIEWS <= self.n_views <= MAX_VIEWS:
            raise ValueError(f'n_views must be in [{MIN_VIEWS}, {MAX_VIEWS}], got {self.n_views}')
        if not 0.0 < self.voxel_fraction < 0.5:
            raise ValueError(f'voxel_fraction must be in (0, 0.5), got {self.voxel_fraction}')
        if self.max_stable_poses < 1 or self.model_samples < 100:
            raise ValueError('max_stable_poses must be >= 1 and model_samples >= 100')


def _samples(vertices: np.ndarray, faces: np.ndarray, count: int, *,
             seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(count, 3) float32 surface points and unit normals ('reflect' scheme), as stored in
    the database; the packaged templates were built from exactly these."""
    points, normals = sample_surface(vertices, faces, count, seed=seed, scheme='reflect')
    return points.astype(np.float32), normals.astype(np.float32)


def _mesh_distance(vertices: np.ndarray, faces: np.ndarray) -> Callable[[np.ndarray], np.ndarray]:
    scene = raycasting_scene(vertices, faces)

    def distance(points: np.ndarray) -> np.ndarray:
        query = o3d_tensor(np.asarray(points, np.float32))
        return cast(np.ndarray, scene.compute_distance(query).numpy())
    return distance


def yaw_period(vertices: np.ndarray, faces: np.ndarray, T_table_object: np.ndarray, *,
               tolerance_m: float, samples: int = 500, seed: int = 0) -> float:
    """Rotational symmetry of a resting object about the table normal through its origin.

    Rotations by 2π/k (k = 36, 4, 3, 2) are tried; the symmetry holds when the rotated surface
    samples lie within ``tolerance_m`` of the mesh (95th percentile).

    Returns:
        the yaw period in radians: 0 for a continuous symmetry, 2π/k, or 2π for none.
    """
    points, _ = _samples(vertices, faces, samples, seed=seed)
    distance = _mesh_distance(vertices, faces)
    axis = invert_transform(T_table_object)[:3, :3] @ np.array([0.0, 0.0, 1.0])
    # about the vertical through the origin first, then through the surface centroid (a CAD
    # origin off the part's centre, e.g. at one end of a tube lying on its side); the table
    # path places each yaw by the centroid, so either axis prunes the same yaws
    for centre in (np.zeros(3), points.mean(axis=0)):
        for k in (36, 4, 3, 2):
            R = rotation_about_axis(axis, 2.0 * np.pi / k)
            if np.percentile(distance((points - centre) @ R.T + centre), 95) < tolerance_m:
                return CONTINUOUS_YAW_PERIOD if k == 36 else 2.0 * np.pi / k
    return 2.0 * np.pi


def listed_yaw_period(symmetries: Symmetries, T_table_object: np.ndarray, *,
                      tolerance_deg: float = 2.0) -> float:
    """The yaw period of a resting object from its listed symmetries (models_info.json, the
    ones the scorer uses): 0 when a continuous axis stands along the table normal, else the
    smallest angle of a listed rotation about the normal (2π/n of an n-fold), 2π for none.
    Unlike :func:`yaw_period`'s mesh test, a disc whose small holes move too few samples to
    tell is not taken for continuous, and any n-fold counts (a 5-fold flange too)."""
    axis = invert_transform(T_table_object)[:3, :3] @ np.array([0.0, 0.0, 1.0])
    cos_tol = np.cos(np.radians(tolerance_deg))
    if any(abs(float(np.dot(a, axis))) >= cos_tol for a, _ in symmetries.continuous):
        return CONTINUOUS_YAW_PERIOD
    # every listed rotation, a continuous axis's composed with the discrete ones (a lying
    # tube's half turn about the normal is one about its axis composed with one across it)
    rotations = symmetries.transforms(step_rad=np.radians(tolerance_deg))[:, :3, :3]
    angles = [rotation_angle_deg(R, np.eye(3)) for R in rotations
              if float(np.dot(R @ axis, axis)) >= cos_tol]   # it keeps the normal
    # (a sampled step about an axis across the normal keeps it too: no yaw)
    angles = [a for a in angles if a > 2.0 * tolerance_deg]
    return float(np.radians(min(angles))) if angles else 2.0 * np.pi


def merge_equivalent_poses(vertices: np.ndarray, faces: np.ndarray,
                           poses: list[tuple[np.ndarray, float]], *, tolerance_m: float,
                           samples: int = 300, yaw_steps: int = 72,
                           seed: int = 0) -> list[tuple[np.ndarray, float]]:
    """Merge stable poses that show the same resting shape up to a yaw (symmetric parts: a
    cylinder lying on its side has one hull facet per side); probabilities are summed.

    ``poses`` must be sorted most probable first; the first of each group is kept.
    """
    points, _ = _samples(vertices, faces, samples, seed=seed)
    distance = _mesh_distance(vertices, faces)
    yaws = 2.0 * np.pi * np.arange(yaw_steps) / yaw_steps
    kept: list[list[Any]] = []
    for T, prob in poses:
        for entry in kept:
            T_kept = entry[0]
            if abs(T_kept[2, 3] - T[2, 3]) > tolerance_m:
                continue  # different heights of the origin: different shapes
            # p on the surface; T p rotated by yaw back into the kept pose's object frame
            moved = [transform_points(invert_transform(T_kept) @ make_transform(
                rotation_about_axis([0, 0, 1], -y), np.zeros(3)) @ T, points) for y in yaws]
            d = distance(np.concatenate(moved)).reshape(len(yaws), -1)
            if np.min(np.percentile(d, 95, axis=1)) < tolerance_m:
                entry[1] += prob
                break
        else:
            kept.append([np.asarray(T, np.float64), float(prob)])
    return [(T, p) for T, p in kept]


def diameter(vertices: np.ndarray) -> float:
    """Largest distance between two vertices, metres."""
    return point_set_diameter(vertices)


def template_from_cloud(points_c: np.ndarray, T_camera_object: np.ndarray, *,
                        voxel_size_m: float, params: TemplateParams = TemplateParams(),
                        stable_index: int = -1, yaw_rad: float = 0.0,
                        with_fpfh: bool = False) -> Template:
    """A template from a captured or rendered partial cloud in its camera frame.

    Args:
        points_c: (N, 3) points of the object only, camera optical frame, metres.
        T_camera_object: (4, 4) pose of the object in that camera frame (e.g. from the
            turntable calibration).
        with_fpfh: compute the FPFH now (otherwise on first use).
    """
    points, normals = preprocess_roi(points_c, voxel_size_m=voxel_size_m, params=params.cloud)
    if len(points) < 10:
        raise ValueError(f'template view has only {len(points)} points after voxelisation; '
                         'is the object visible?')
    fpfh = compute_fpfh(points, normals, radius_m=params.fpfh_radius_voxels * voxel_size_m,
                        max_nn=params.fpfh_max_nn) if with_fpfh else None
    return Template(points.astype(np.float32), normals.astype(np.float32), fpfh,
                    np.asarray(T_camera_object, np.float64), stable_index, float(yaw_rad))


def build_object_templates(
        obj_id: int, vertices: np.ndarray, faces: np.ndarray,
        stable_poses: Iterable[tuple[np.ndarray, float]], *, intrinsics: CameraIntrinsics,
        T_world_camera: np.ndarray, params: TemplateParams = TemplateParams(),
        diameter_m: float | None = None,
        position_m: np.ndarray | None = None,
        symmetries: Symmetries | None = None) -> ObjectTemplates:
    """Render the turntable templates of one object.

    The object rests on the table (world z = 0) at ``position_m`` (default: where the camera's
    optical axis meets the table) in each of its most probable stable poses and is turned by
    ``2π k / n_views``; each view is ray-cast from the camera, back-projected and voxelised
    (FPFH on first use).

    Args:
        obj_id: T-LESS id.
        vertices: (V, 3) mesh vertices in metres (object frame); faces: (F, 3) int.
        stable_poses: (T_table_object (4, 4), probability) pairs, e.g. from
            ``tlessbot_ros.io.models.stable_poses``.
        intrinsics, T_world_camera: the rendering camera (the rig's side camera).
        diameter_m: the object's diameter (computed from the vertices if None).
        position_m: (3,) turntable centre on the table in world coordinates.
        symmetries: the part's listed symmetries, which give its exact yaw periods
            (:func:`listed_yaw_period`; the flat check turns a round part by their steps) and
            the exact symmetries of the near-symmetric turn check; None: none listed.
    """
    from tlessbot_ros.core.common import MeshRenderer

    poses = sorted(((np.asarray(T, np.float64), float(p)) for T, p in stable_poses),
                   key=lambda pair: -pair[1])
    if not poses:
        raise ValueError(f'obj_{obj_id:02d}: at least one stable pose is needed')
    diam = float(diameter_m) if diameter_m else diameter(vertices)
    # Merge first: a part lying on its curved side has many hull facets, each improbable, that
    # together are often its most probable pose.
    poses = merge_equivalent_poses(vertices, faces, poses, tolerance_m=0.015 * diam)
    poses.sort(key=lambda pair: -pair[1])
    poses = [pair for pair in poses if pair[1] >= params.min_stable_probability] or poses[:1]
    voxel = diam * params.voxel_fraction
    model_points, model_normals = _samples(vertices, faces, params.model_samples,
                                           seed=params.seed)
    periods = np.array([yaw_period(vertices, faces, T, tolerance_m=0.01 * diam)
                        for T, _ in poses])
    listed = None if symmetries is None else np.array(
        [listed_yaw_period(symmetries, T) for T, _ in poses])
    if position_m is None:
        position_m = _optical_axis_on_table(T_world_camera)
    T_camera_world = invert_transform(T_world_camera)
    templates = []
    for s, (T_table_object, _) in enumerate(poses[:params.max_stable_poses]):
        for k in range(params.n_views):
            yaw = 2.0 * np.pi * k / params.n_views
            T_world_object = make_transform(rotation_about_axis([0, 0, 1], yaw),
                                            position_m) @ T_table_object
            renderer = MeshRenderer()
            renderer.add_mesh(vertices, faces, T_world_object)
            view = renderer.render(intrinsics, T_world_camera)
            points, _ = depth_to_points(view.depth_m, intrinsics.K, mask=view.instance == 0)
            templates.append(template_from_cloud(
                points, T_camera_world @ T_world_object, voxel_size_m=voxel, params=params,
                stable_index=s, yaw_rad=yaw))
    return ObjectTemplates(
        obj_id=int(obj_id), diameter_m=diam, voxel_size_m=voxel, model_points=model_points,
        model_normals=model_normals, stable_poses=np.array([T for T, _ in poses]),
        stable_probabilities=np.array([p for _, p in poses]), yaw_periods=periods,
        listed_yaw_periods=listed, listed_rotations=None if symmetries is None else
        symmetries.transforms(step_rad=np.radians(2.0))[:, :3, :3],
        templates=templates, normal_radius_voxels=params.cloud.normal_radius_voxels,
        normal_max_nn=params.cloud.normal_max_nn, fpfh_radius_voxels=params.fpfh_radius_voxels,
        fpfh_max_nn=params.fpfh_max_nn)


def _optical_axis_on_table(T_world_camera: np.ndarray) -> np.ndarray:
    origin, axis = T_world_camera[:3, 3], T_world_camera[:3, 2]
    if axis[2] >= -1e-6:
        raise ValueError('the camera does not look down at the table (z = 0)')
    return cast(np.ndarray, origin + axis * (-origin[2] / axis[2]))


def build_database(models: Iterable[tuple[int, np.ndarray, np.ndarray,
                                          list[tuple[np.ndarray, float]], float | None]], *,
                   intrinsics: CameraIntrinsics, T_world_camera: np.ndarray,
                   params: TemplateParams = TemplateParams(),
                   progress: Callable[[Iterable[Any]], Iterable[Any]] | None = None,
                   keep_meshes: bool = True,
                   symmetries: Mapping[int, Symmetries | None] | None = None) -> TemplateDatabase:
    """Templates of several objects: ``models`` yields (obj_id, vertices m, faces,
    stable poses, diameter_m or None); ``progress`` wraps the iterable (e.g. ``tqdm``).
    ``keep_meshes``: store every part's mesh (off: only look-alikes' and flat parts').
    ``symmetries``: each part's listed symmetries, by id (:func:`build_object_templates`)."""
    items = list(models)
    db = TemplateDatabase(params={**{k: v for k, v in asdict(params).items() if k != 'cloud'},
                                  'T_world_camera': np.asarray(T_world_camera).tolist(),
                                  'K': intrinsics.K.tolist(),
                                  'image_size': [intrinsics.width, intrinsics.height]})
    for obj_id, vertices, faces, poses, diam in (progress(items) if progress else items):
        db.objects[int(obj_id)] = build_object_templates(
            obj_id, vertices, faces, poses, intrinsics=intrinsics,
            T_world_camera=T_world_camera, params=params, diameter_m=diam,
            symmetries=(symmetries or {}).get(int(obj_id)))
    meshes = {int(obj_id): (vertices, faces) for obj_id, vertices, faces, _, _ in items}
    for obj_id, others in lookalike_pairs(meshes, tolerance_m=params.lookalike_tolerance_m,
                                          min_shared=params.lookalike_min_shared).items():
        obj = db.objects[obj_id]
        obj.lookalikes = others
        obj.mesh_vertices = np.asarray(meshes[obj_id][0], np.float32)
        obj.mesh_faces = np.asarray(meshes[obj_id][1], np.int32)
    for obj_id, (vertices, faces) in meshes.items():
        # every part's mesh: the flat check (flat parts) and the turn check (near-symmetric
        # parts, :mod:`tlessbot_ros.core.pose.turns`) render it
        obj = db.objects[obj_id]
        if obj.mesh_faces is None and (keep_meshes or is_flat_mesh(vertices)):
            obj.mesh_vertices = np.asarray(vertices, np.float32)
            obj.mesh_faces = np.asarray(faces, np.int32)
    return db


def resting_pose(vertices: np.ndarray) -> np.ndarray:
    """A simple ``T_table_object`` for tests and fall-backs: the object unrotated, lifted so
    its lowest vertex touches z = 0 (not necessarily a physically stable pose)."""
    return make_transform(np.eye(3), [0.0, 0.0, -float(np.min(np.asarray(vertices)[:, 2]))])
