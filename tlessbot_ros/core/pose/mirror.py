"""Flat parts and their mirror image: which face is up, told by what the depth cannot see.

A part a few millimetres thick shows the depth camera one flat face. Turned upside down
(a half turn about an axis in the table plane) it shows the same flat face at the same height,
and its outline becomes the mirror image of the true one: the depth fit explains the ROI cloud
about as well either way (on a spanner 4 mm thick, 3 of 13 poses within 5 cm / 5° although
ADD-S, blind to the turn, accepts all 13). The outline itself is not blind to it: an
asymmetric plate, a bracket or a spanner turned over shows its corner cut, its holes and its
jaw on the other side.

:class:`MirrorCheck` runs after the depth fit of a flat part (resting height at most
``flat_ratio`` of its diameter): the fitted pose turned over about ``flips`` horizontal axes
through the part's centre, and turned end for end about the vertical, is fitted to the depth
again (a short ICP from each start, bounded: a fixed count of starts, not a time budget); the
turned fits that explain the depth about as well as the winner (within ``fitness_margin``)
compete with it on the image. Each pose's silhouette is projected into every view that sees
the part, and (:mod:`~tlessbot_ros.core.pose.silhouette`)

* the pixels where two silhouettes differ vote by their colour: like the part (the pixels both
  cover) or like its surroundings (a ring just outside both), for the silhouette that calls
  them so; a turned pose wins with more than ``min_share`` of at least ``min_disputed_px``;
* with fewer disputed pixels, the silhouettes' agreement with the colour image's edges (the
  share of the outline, holes included, within a few pixels of a Canny edge: Canny, PAMI
  1986; a one-sided chamfer match as in Barrow et al., IJCAI 1977) and with the localiser's
  label mask decides, by ``min_gain``.

The winner gets the fitted pose's polish. :func:`refine_yaw` then checks the yaw on the image
(the depth of a part 3 mm thin holds it only by its few edge points).

Poses are ``T_camera_object`` (4, 4) float64, metres, optical frame.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, cast

import numpy as np

from tlessbot_ros.core.common import (
    CameraIntrinsics,
    invert_transform,
    rotation_about_axis,
    transform_points,
)
from tlessbot_ros.core.pose.silhouette import (
    agreement,
    disputed_votes,
    edge_distance,
    silhouette,
    window,
)

if TYPE_CHECKING:   # this module is light: core.params imports MirrorParams
    from tlessbot_ros.core.pose.database import ObjectTemplates
    from tlessbot_ros.core.pose.refinement import Refiner


@dataclass(frozen=True)
class MirrorParams:
    """Settings of :class:`MirrorCheck` (the generated plates rest 0.03-0.06 of their
    diameter high, a 20 mm block 0.34; no T-LESS part under 0.26, so none is checked).

    Attributes:
        enabled: check flat parts' face, yaw and look-alike on the colour image.
        flat_ratio: a part is flat when it rests at most this share of its diameter high (0..1).
        flips: horizontal half-turn axes tried, spread over 180° (>= 1).
        upright: also try the pose turned end for end about the vertical.
        fitness_margin: a turned fit competes when its depth fitness is at most this much lower
            (0..1).
        candidates: turned fits that compete at most, best by depth fitness first (>= 1).
        min_gain: with few disputed pixels, a turned pose needs this much more edge/label
            agreement (0..1).
        min_disputed_px: pixels where two silhouettes differ needed for the colour vote (>= 1).
        min_share: a turned pose wins the colour vote with more than this share (0.5..1).
        iou_weight: weight of the label mask's IoU beside the edge agreement (>= 0).
        edge_px: an outline pixel agrees when a colour edge is this near, px (> 0).
        icp_iterations: ICP steps of each turned start (>= 1).
        yaw_steps, yaw_step_deg: the yaw checked on the image this many steps of this many deg
            either way (0 steps: off).
        yaw_min_gain: a new yaw is kept when its agreement gains more than this (0..1).
    """

    enabled: bool = True
    flat_ratio: float = 0.12
    flips: int = 8
    upright: bool = True
    fitness_margin: float = 0.1
    candidates: int = 4
    min_gain: float = 0.04
    min_disputed_px: int = 20
    min_share: float = 0.6
    iou_weight: float = 0.5
    edge_px: float = 2.0
    icp_iterations: int = 12
    yaw_steps: int = 4
    yaw_step_deg: float = 1.5
    yaw_min_gain: float = 0.02

    def __post_init__(self) -> None:
        if self.flips < 1 or self.candidates < 1 or self.icp_iterations < 1 or \
                self.min_disputed_px < 1 or self.yaw_steps < 0:
            raise ValueError('flips, candidates, icp_iterations and min_disputed_px must be '
                             '>= 1 and yaw_steps >= 0')
        if not 0.5 <= self.min_share <= 1.0 or self.iou_weight < 0 or self.yaw_step_deg <= 0:
            raise ValueError(f'min_share must be in 0.5..1, iou_weight >= 0, yaw_step_deg > 0; '
                             f'got {self.min_share}, {self.iou_weight}, {self.yaw_step_deg}')
        if not 0.0 <= self.flat_ratio <= 1.0 or self.edge_px <= 0:
            raise ValueError('flat_ratio must be in [0, 1] and edge_px positive')


@dataclass(frozen=True)
class ViewEvidence:
    """What one camera shows of a part: ``rgb`` (H, W, 3) uint8, ``mask`` (H, W) bool (the
    localiser's label of the part; may be empty), its ``intrinsics`` and ``T_view_fit``
    (4, 4): the transform from the fitted view's optical frame into this one's (identity for
    the fitted view itself)."""

    rgb: np.ndarray
    mask: np.ndarray
    intrinsics: CameraIntrinsics
    T_view_fit: np.ndarray


def is_flat(obj: ObjectTemplates, ratio: float) -> bool:
    """Whether ``obj`` rests at most ``ratio`` of its diameter high (its most probable stable
    pose; cached on the object)."""
    height = obj.derived('resting_height', lambda: float(np.ptp(
        transform_points(obj.stable_poses[0], obj.model_points.astype(np.float64))[:, 2])))
    return cast(bool, height <= ratio * obj.diameter_m)


def flipped_poses(T_world_object: np.ndarray, centre_o: np.ndarray, count: int, *,
                  upright: bool = False) -> np.ndarray:
    """(count, 4, 4) ``T_world_object`` turned by half a turn about ``count`` horizontal axes
    (180°/count apart) through the object point ``centre_o`` (3,) (its bounding-box centre:
    the turned part occupies the same heights); with ``upright`` one more, turned about the
    vertical (the same face up, end for end: a near-symmetric outline fits the depth both
    ways too)."""
    T_world_object = np.asarray(T_world_object, np.float64)
    centre_w = transform_points(T_world_object, np.asarray(centre_o, np.float64)[None])[0]
    axes = [np.array([np.cos(a), np.sin(a), 0.0]) for a in np.pi * np.arange(count) / count]
    axes += [np.array([0.0, 0.0, 1.0])] if upright else []
    out = np.tile(T_world_object, (len(axes), 1, 1))
    for k, axis in enumerate(axes):
        R = rotation_about_axis(axis, np.pi)
        out[k, :3, :3] = R @ T_world_object[:3, :3]
        out[k, :3, 3] = R @ (T_world_object[:3, 3] - centre_w) + centre_w
    return out


class MirrorCheck:
    """Turns a flat part's fitted pose over when the image says the other face is up.

    Args:
        refiner: the pose stage's :class:`~tlessbot_ros.core.pose.Refiner` (ICP and fitness).
        params: :class:`MirrorParams`.
        voxel_scale: the ROI's voxel edge in object voxels (``PoseParams.table_voxel_scale``).
    """

    def __init__(self, refiner: Refiner, params: MirrorParams = MirrorParams(), *,
                 voxel_scale: float = 1.0, sor_neighbors: int = 20,
                 sor_std_ratio: float = 2.0) -> None:
        self.refiner = refiner
        self.params = params
        self.voxel_scale = voxel_scale
        self._sor = (sor_neighbors, sor_std_ratio)

    def applies(self, obj: ObjectTemplates) -> bool:
        """Whether ``obj`` is checked at all (enabled, and a flat part)."""
        return self.params.enabled and is_flat(obj, self.params.flat_ratio)

    def flipped_fits(self, obj: ObjectTemplates, T_camera_object: np.ndarray,
                     points_c: np.ndarray, T_world_camera: np.ndarray
                     ) -> tuple[float, list[tuple[np.ndarray, float]], np.ndarray]:
        """The fitted pose's depth fitness, the flipped fits that compete with it
        (``(T_camera_object, fitness)`` best first, at most ``candidates`` of them) and the
        prepared ROI cloud they were fitted to."""
        from tlessbot_ros.core.pose.cloud import remove_statistical_outliers, voxel_downsample

        p = self.params
        scene, _ = voxel_downsample(np.asarray(points_c, np.float64),
                                    obj.voxel_size_m * self.voxel_scale)
        if len(scene) >= 10:
            scene = scene[remove_statistical_outliers(scene, neighbors=self._sor[0],
                                                      std_ratio=self._sor[1])]
        centre = _centre(obj)
        T_world_object = T_world_camera @ T_camera_object
        starts = invert_transform(T_world_camera) @ flipped_poses(
            T_world_object, centre, p.flips, upright=p.upright)
        refined = self.refiner.icp_batch(scene, obj, starts, iterations=p.icp_iterations)
        fitness = self.refiner.grid_fitness(np.concatenate([T_camera_object[None], refined]),
                                            scene, obj)
        own, flipped = float(fitness[0]), fitness[1:]
        chosen: list[tuple[np.ndarray, float]] = []
        for k in np.argsort(-flipped, kind='stable'):
            if len(chosen) == p.candidates or flipped[k] < own - p.fitness_margin:
                break
            if all(_differ(refined[k], T) for T, _ in chosen):
                chosen.append((refined[k], float(flipped[k])))
        return own, chosen, scene

    def image_evidence(self, obj: ObjectTemplates, poses: Sequence[np.ndarray],
                       views: Sequence[ViewEvidence]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """For K poses (the fitted one first): (K,) mean :func:`agreement` over the views,
        (K,) share of the pixels disputed between pose k and pose 0 that vote for pose k
        (:func:`disputed_votes`, summed over the views; 0.5 for pose 0 and without any) and
        (K,) the count of those pixels. Each view is read in the window around all the
        poses' silhouettes."""
        p = self.params
        points = obj.model_points.astype(np.float64)
        spacing = obj.derived('sample_spacing', lambda: _sample_spacing(points))
        scores = np.zeros(len(poses))
        votes = np.zeros((len(poses), 2))
        used = 0
        for view in views:
            T = [view.T_view_fit @ np.asarray(T_k, np.float64) for T_k in poses]
            box = window(points, T, view.intrinsics, margin_px=8)
            if box is None:
                continue
            x0, y0, w, h = box
            distance = edge_distance(view.rgb, box)
            label = np.asarray(view.mask[y0:y0 + h, x0:x0 + w], bool)
            rgb = view.rgb[y0:y0 + h, x0:x0 + w]
            masks = [silhouette(points, T_k, view.intrinsics, box, spacing) for T_k in T]
            for k, mask in enumerate(masks):
                scores[k] += agreement(mask, distance, label, edge_px=p.edge_px,
                                       iou_weight=p.iou_weight)
                if k:
                    votes[k] += disputed_votes(masks[0], mask, rgb)[::-1]
            used += 1
        total = votes.sum(axis=1)
        share = np.where(total > 0, votes[:, 0] / np.maximum(total, 1), 0.5)
        return scores / max(used, 1), share, total

    def resolve(self, obj: ObjectTemplates, T_camera_object: np.ndarray, points_c: np.ndarray,
                T_world_camera: np.ndarray, views: Sequence[ViewEvidence]
                ) -> tuple[np.ndarray | None, dict[str, float]]:
        """The turned pose that replaces the fitted one (None: keep it) and what decided:
        ``{'fitness', 'flip_fitness', 'agreement', 'flip_agreement', 'flip_share',
        'disputed_px'}`` (only the fitness when no turned fit competes).

        With at least ``min_disputed_px`` pixels disputed between the two silhouettes, the
        turned pose wins when more than ``min_share`` of them vote for it (and its agreement
        is not lower by more than ``min_gain``); with fewer, when its agreement is higher by
        more than ``min_gain``."""
        p = self.params
        own, flipped, scene = self.flipped_fits(obj, np.asarray(T_camera_object, np.float64),
                                                points_c, np.asarray(T_world_camera, np.float64))
        info = {'fitness': own}
        if not flipped:
            return None, info
        scores, share, disputed = self.image_evidence(
            obj, [T_camera_object] + [T for T, _ in flipped], views)
        decided = disputed >= p.min_disputed_px
        gain = np.where(decided, share - p.min_share, scores - scores[0] - p.min_gain)
        k = 1 + int(np.argmax(gain[1:]))
        info.update(flip_fitness=flipped[k - 1][1], agreement=float(scores[0]),
                    flip_agreement=float(scores[k]), flip_share=float(share[k]),
                    disputed_px=float(disputed[k]))
        if gain[k] > 0 and (not decided[k] or scores[k] >= scores[0] - p.min_gain):
            # the winner gets the polish the fitted pose had (every ROI point, more steps)
            pose = self.refiner.params
            T = self.refiner.icp_batch(scene, obj, flipped[k - 1][0][None],
                                       iterations=max(pose.polish_iterations, p.icp_iterations),
                                       points=len(scene),
                                       distance_m=pose.polish_distance_voxels * obj.voxel_size_m)
            return T[0], info
        return None, info


def refine_yaw(check: MirrorCheck, obj: ObjectTemplates, T_camera_object: np.ndarray,
               T_world_camera: np.ndarray, views: Sequence[ViewEvidence]
               ) -> tuple[np.ndarray, float]:
    """A flat part's pose turned about the vertical through its centre by the yaw among
    ``yaw_steps`` steps of ``yaw_step_deg`` either way whose silhouette agrees best with the
    image (:func:`agreement`); the fitted pose unless that gains more than ``yaw_min_gain``.
    The depth of a part 3 mm thin holds its yaw only by its few edge points (measured: 4-6°
    off on a 60 x 40 x 3 mm plate); its outline in the image holds it better. Returns the pose
    and the yaw (degrees) it was turned by."""
    p = check.params
    T_camera_object = np.asarray(T_camera_object, np.float64)
    if p.yaw_steps < 1:
        return T_camera_object, 0.0
    yaws = p.yaw_step_deg * np.arange(-p.yaw_steps, p.yaw_steps + 1)
    centre = _centre(obj)
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


def _centre(obj: ObjectTemplates) -> np.ndarray:
    """(3,) the centre of the object's bounding box, object frame (cached on the object)."""
    return cast(np.ndarray, obj.derived('bbox_centre', lambda: (
        obj.model_points.min(axis=0) + obj.model_points.max(axis=0)).astype(np.float64) / 2))


def _differ(T_a: np.ndarray, T_b: np.ndarray) -> bool:
    from tlessbot_ros.core.pose.candidates import poses_differ
    return poses_differ(T_a, T_b)


def _sample_spacing(points: np.ndarray) -> float:
    """Median distance (m) from a model sample to its nearest neighbour."""
    from scipy.spatial import cKDTree

    distance, _ = cKDTree(points).query(points, k=2)
    return float(np.median(distance[:, 1]))
