"""The resting-pose prior: a part that sits on the table rests in one of its stable poses.

A part lying on a table is in one of the resting poses of its convex hull
(:func:`tlessbot_ros.core.common.resting.resting_poses`, the quasi-static model the simulator
draws parts from; the same physics holds in a real cell): its gravity direction, read in the
part's frame, is the outward normal of a stable hull face. A free 6-DOF fit of a small part
(a few dozen depth points) can stop tilted by the depth's noise away from every such
direction, a pose no resting part can have.

:func:`settle` takes a fit whose lowest point touches the table (within ``contact_m``) and whose
gravity direction is more than ``min_tilt_deg`` from every stable pose's (modulo the part's
listed symmetries), tilts it onto the nearest stable poses by the least rotation (its yaw
kept), lowers each onto the table, refits it in (yaw, x, y) on the table (the pose stage's
planar Gauss-Newton) and keeps the best one only when it explains the depth as well as the free
fit: as large a share of the depth points within ``tolerance_m`` of its surface (about two
depth-noise widths: a tilt the depth cannot resolve is not measured), less ``fitness_margin``;
among the levelled poses the one that explains most points (then the lowest RMSE) competes.
A part that leans on a neighbour (its lowest point above the table, or no stable pose that
fits) keeps its fit.

Poses are ``T_camera_object`` (4, 4) metres in the optical frame; the table frame is
``T_world_camera`` with the table at world z = 0.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, cast

import numpy as np

from tlessbot_ros.core.common import invert_transform, transform_points
from tlessbot_ros.core.pose.fallback import rotation_between

if TYPE_CHECKING:
    from tlessbot_ros.core.pose.database import ObjectTemplates
    from tlessbot_ros.core.pose.refinement import Refiner

DOWN = np.array([0.0, 0.0, -1.0])
RESTING_KEY = ('stable_downs',)


@dataclass(frozen=True)
class RestingParams:
    """Settings of the resting-pose prior (:func:`settle`).

    Attributes:
        enabled: level a fit that sits on the table onto the nearest stable poses of its part.
        min_tilt_deg: a fit whose gravity direction is within this of a stable pose's is left
            as it is, deg (>= 0).
        max_tilt_deg: the stable poses within this of the fit's gravity direction are tried,
            deg (> min_tilt_deg).
        candidates: at most this many of them, nearest first (>= 1).
        contact_m: a fit sits on the table when its lowest point is within this of the
            table plane, m (> 0).
        tolerance_m: a depth point is explained within this of the surface, m (> 0; about two
            depth-noise widths).
        noise_ratio: or within this many times the depth noise neighbouring pixels share on
            the table around the part, where more (>= 0; 0: tolerance_m alone).
        fitness_margin: a levelled pose is taken when it explains at most this share of the
            depth points fewer than the free fit (0..1).
        edge_yaw_deg: a levelled pose is then turned about the vertical by at most this where
            its edges lie best on the image's, deg (>= 0; 0: not refined on the image).
        edge_shift_m: and moved along the table by at most this in x and y, m (>= 0).
        edge_cap_px: a rendered edge farther than this from the image's edges counts as this
            far, px (> 0).
        edge_min_reach_px: a view refines a part only where its edges reach this far from its
            centre in the image, px (>= 0; at 12 a 5 deg turn moves them a pixel).
        edge_rested_round: a round flat part's fit that rests on a face already is refined on
            the image's edges too (only its holes hold its yaw).
        edge_round_period: ... turned by up to half its listed yaw period either way, where
            that is more than ``edge_yaw_deg`` (its fitted yaw may be any turn off).
        edge_round_levelled: ... and so is one levelled onto a face (a tilted fit's yaw is
            no better held).
        edge_round_thick: a round part with holes that is not flat (a flange) is refined as
            a round flat part is.
    """

    enabled: bool = True
    min_tilt_deg: float = 2.0
    max_tilt_deg: float = 30.0
    candidates: int = 3
    contact_m: float = 0.004
    tolerance_m: float = 0.002
    # a part's own smoothed depth reads noisier than the table's around it, and a lying
    # plate's free fit, tilted by that noise, explains more of it than the level pose unless
    # the tolerance leaves room for that difference
    noise_ratio: float = 4.0
    fitness_margin: float = 0.02
    edge_yaw_deg: float = 10.0
    edge_shift_m: float = 0.003
    edge_cap_px: float = 3.0
    edge_min_reach_px: float = 12.0
    edge_rested_round: bool = True
    edge_round_period: bool = True
    edge_round_levelled: bool = True
    edge_round_thick: bool = True

    def __post_init__(self) -> None:
        if not 0.0 <= self.min_tilt_deg < self.max_tilt_deg <= 180.0:
            raise ValueError('need 0 <= min_tilt_deg < max_tilt_deg <= 180 degrees, got '
                             f'{self.min_tilt_deg}, {self.max_tilt_deg}')
        if self.candidates < 1 or self.contact_m <= 0 or self.tolerance_m <= 0 or \
                not 0 <= self.fitness_margin <= 1 or self.noise_ratio < 0 or \
                min(self.edge_yaw_deg, self.edge_shift_m, self.edge_min_reach_px) < 0 or \
                self.edge_cap_px <= 0:
            raise ValueError('candidates must be >= 1, contact_m and tolerance_m > 0, '
                             'fitness_margin in 0..1, noise_ratio, edge_yaw_deg, edge_shift_m '
                             f'and edge_min_reach_px >= 0, edge_cap_px > 0, got {self}')


def stable_directions(obj: ObjectTemplates) -> np.ndarray | None:
    """(S, 4) float64 per stable pose of ``obj``'s mesh: the gravity direction in the part's
    frame (the stable hull face's outward normal) and the pose's probability, most probable
    first (every pose, none merged); None without a mesh. Built once per part (cached with the
    start-up listings, :mod:`tlessbot_ros.core.pose.derived`)."""
    from tlessbot_ros.core.common.resting import resting_poses

    vertices, faces = obj.mesh_vertices, obj.mesh_faces
    if vertices is None or faces is None:
        return None

    def build() -> np.ndarray:
        poses = resting_poses(np.asarray(vertices, np.float64), faces, obj.diameter_m)
        return np.array([[*(T[:3, :3].T @ DOWN), p] for T, p in poses],
                        np.float64).reshape(-1, 4)
    return cast(np.ndarray, obj.derived(RESTING_KEY, build))


def stable_offsets(obj: ObjectTemplates, R_world_object: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray]:
    """(S,) angle (deg) between the gravity direction of a part turned by ``R_world_object``
    (read in its frame) and each stable pose's, modulo the part's listed symmetries, and (S, 3)
    the symmetric image of each stable direction that is nearest. Empty without a mesh."""
    table = stable_directions(obj)
    if table is None or not len(table):
        return np.zeros(0), np.zeros((0, 3))
    down_o = np.asarray(R_world_object, np.float64)[:3, :3].T @ DOWN
    rotations = obj.listed_rotations if obj.listed_rotations is not None else np.eye(3)[None]
    images = np.einsum('kij,sj->ksi', rotations, table[:, :3])          # (K, S, 3)
    cos = images @ down_o                                                # (K, S)
    best = np.argmax(cos, axis=0)
    nearest = images[best, np.arange(images.shape[1])]
    angle = np.degrees(np.arccos(np.clip(cos[best, np.arange(cos.shape[1])], -1.0, 1.0)))
    return angle, nearest


def contact_points(obj: ObjectTemplates) -> np.ndarray:
    """(N, 3) float64 the points of ``obj`` that can touch the table: its mesh vertices, or
    its surface samples without a mesh."""
    vertices = obj.mesh_vertices if obj.mesh_vertices is not None else obj.model_points
    return np.asarray(vertices, np.float64)


def levelled(T_world_object: np.ndarray, targets_o: np.ndarray, points_o: np.ndarray,
             centre_o: np.ndarray) -> np.ndarray:
    """(K, 4, 4) ``T_world_object`` turned, about the part's ``centre_o``, by the least rotation
    that points each of (K, 3) ``targets_o`` (directions in the part's frame) straight down,
    then lowered or raised so that the lowest of ``points_o`` touches the table (z = 0)."""
    T = np.asarray(T_world_object, np.float64)
    centre = T[:3, :3] @ centre_o + T[:3, 3]
    out = np.repeat(T[None], len(targets_o), axis=0)
    for k, target in enumerate(np.asarray(targets_o, np.float64)):
        R = rotation_between(T[:3, :3] @ target, DOWN)
        out[k, :3, :3] = R @ T[:3, :3]
        out[k, :3, 3] = centre + R @ (T[:3, 3] - centre)
        out[k, 2, 3] -= float(np.min(points_o @ out[k, :3, :3].T[:, 2] + out[k, 2, 3]))
    return out


def level_starts(obj: ObjectTemplates, T_world_object: np.ndarray, params: RestingParams
                 ) -> tuple[np.ndarray, dict[str, float]]:
    """(K, 4, 4) ``T_world_object`` of the fit levelled onto each of the stable poses of
    ``obj`` that :func:`settle` tries (:func:`levelled`; none when the fit does not sit on the
    table, rests already or has no stable pose within ``max_tilt_deg``) and the fit's
    ``rest_tilt_deg``, ``rest_contact_m``, ``rest_tried`` (0) and ``rest_levelled`` (0)."""
    T_wo = np.asarray(T_world_object, np.float64)
    angle, nearest = stable_offsets(obj, T_wo[:3, :3])
    points_o = contact_points(obj)
    height = float(np.min(transform_points(T_wo, points_o)[:, 2])) if len(angle) else 0.0
    info = {'rest_tilt_deg': float(angle.min()) if len(angle) else 0.0,
            'rest_contact_m': height, 'rest_tried': 0.0, 'rest_levelled': 0.0}
    order = [] if not len(angle) or abs(height) > params.contact_m or \
        angle.min() <= params.min_tilt_deg else \
        [int(s) for s in np.argsort(angle, kind='stable')
         if angle[s] <= params.max_tilt_deg][:params.candidates]
    if not order:
        return np.zeros((0, 4, 4)), info
    centre_o = obj.derived('surface_centre',
                           lambda: obj.model_points.mean(axis=0).astype(np.float64))
    return levelled(T_wo, nearest[order], points_o, centre_o), info


def rest_tolerance_m(params: RestingParams, noise_m: float) -> float:
    """How near its surface a depth point must lie to be explained (m): ``tolerance_m``, or
    ``noise_ratio`` times the depth noise ``noise_m`` around the part where that is more."""
    return max(params.tolerance_m, params.noise_ratio * noise_m)


def settle(refiner: Refiner, obj: ObjectTemplates, T_camera_object: np.ndarray,
           scene_c: np.ndarray, T_world_camera: np.ndarray, params: RestingParams, *,
           noise_m: float = 0.0) -> tuple[np.ndarray | None, dict[str, float]]:
    """The fit levelled onto a stable pose of its part, or None (the fit stands).

    Args:
        refiner: the pose stage's refinement and scoring.
        obj: the part's templates (its mesh gives the stable poses).
        T_camera_object: the fit.
        scene_c: (N, 3) the ROI cloud as the fit saw it (optical frame, m).
        T_world_camera: the table frame (table at world z = 0).
        params: the settings.
        noise_m: the depth noise neighbouring pixels share around the part (m, a robust sigma;
            :func:`~tlessbot_ros.core.pose.flat_align.table_noise_m`; 0: unknown).

    Returns:
        the levelled pose (None when the part does not sit on the table, rests already,
        has no stable pose near enough, or none fits as well) and what decided:
        ``rest_tilt_deg`` (the fit's angle from the nearest stable pose), ``rest_contact_m``
        (its lowest point's height), ``rest_tried``, ``rest_fitness`` and ``rest_rmse_m``
        (the free fit's, at ``rest_tolerance_m``: ``tolerance_m``, or ``noise_ratio`` times
        ``noise_m`` where that is more), ``rest_best_fitness`` and ``rest_best_rmse_m``
        (the best levelled pose's) and ``rest_levelled``.
    """
    T_wc = np.asarray(T_world_camera, np.float64)
    T_co = np.asarray(T_camera_object, np.float64)
    starts, info = level_starts(obj, T_wc @ T_co, params)
    if not len(starts) or len(scene_c) < 10:
        return None, info
    scene_w = transform_points(T_wc, scene_c)
    sub = scene_w[::max(1, len(scene_w) // refiner.params.score_points)]
    settled, _ = refiner.planar(starts, sub, obj, tau=obj.voxel_size_m)
    T_cw = invert_transform(T_wc)
    poses = np.einsum('ij,kjl->kil', T_cw, settled)
    # a smoothed depth's shared noise tilts a small part's fit as a whole: a tilt within it
    # is not measured, so the levelled pose is judged at that noise, not at the per-pixel one
    tolerance = rest_tolerance_m(params, noise_m)
    fits = [refiner.surface_fit(scene_c, obj, T, inlier_m=tolerance)
            for T in np.concatenate([T_co[None], poses])]
    k = min(range(len(poses)), key=lambda j: (-fits[1 + j][0], fits[1 + j][1]))
    info.update(rest_tried=float(len(starts)), rest_fitness=fits[0][0],
                rest_best_fitness=fits[1 + k][0], rest_rmse_m=fits[0][1],
                rest_best_rmse_m=fits[1 + k][1], rest_tolerance_m=tolerance)
    if fits[1 + k][0] < fits[0][0] - params.fitness_margin:
        return None, info
    info['rest_levelled'] = 1.0
    return poses[k], info


__all__ = ['RestingParams', 'contact_points', 'level_starts', 'levelled', 'rest_tolerance_m',
           'settle',
           'stable_directions', 'stable_offsets']
