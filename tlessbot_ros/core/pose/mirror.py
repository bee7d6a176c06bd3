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
through the part's centre is fitted to the depth again (a short ICP from each start, bounded:
a fixed count of starts, not a time budget); the flipped fits that explain the depth about as
well as the winner (within ``fitness_margin``) compete with it on the image: each pose's
silhouette, projected into every view that sees the part, is compared with

* the colour image's edges: the share of the silhouette's outline (holes included) within a
  few pixels of a Canny edge (Canny, PAMI 1986; a chamfer match as in Barrow et al., IJCAI
  1977), and
* the localiser's label mask of the part (intersection over union),

and a flipped pose replaces the winner only when it agrees better by ``min_gain``.

Poses are ``T_camera_object`` (4, 4) float64, metres, optical frame.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from tlessbot_ros.core.common import (
    CameraIntrinsics,
    invert_transform,
    rotation_about_axis,
    transform_points,
)

if TYPE_CHECKING:   # this module is light: core.params imports MirrorParams
    from tlessbot_ros.core.pose.database import ObjectTemplates
    from tlessbot_ros.core.pose.refinement import Refiner


@dataclass(frozen=True)
class MirrorParams:
    """Settings of :class:`MirrorCheck`.

    Attributes:
        enabled: run the check at all.
        flat_ratio: a part is flat when its most probable resting height is at most this
            share of its diameter (the generated plates 0.03-0.06, a 20 mm block 0.34; no
            T-LESS part is under 0.2).
        flips: horizontal half-turn axes tried, evenly spaced over 180° (the flipped part's
            yaw then steps by 360°/flips before the ICP).
        fitness_margin: a flipped fit competes when its depth fitness is at most this much
            below the winner's.
        candidates: at most this many flipped fits compete (the best by depth fitness).
        min_gain: a flipped pose wins when its image agreement beats the fitted pose's by
            more than this (agreement in [0, 1]).
        iou_weight: weight of the label mask's IoU beside the edge agreement.
        edge_px: an outline pixel agrees when a colour edge lies within this many pixels.
        icp_iterations: ICP steps of each flipped start.
    """

    enabled: bool = True
    flat_ratio: float = 0.12
    flips: int = 8
    fitness_margin: float = 0.1
    candidates: int = 2
    min_gain: float = 0.04
    iou_weight: float = 0.5
    edge_px: float = 2.0
    icp_iterations: int = 12

    def __post_init__(self) -> None:
        if self.flips < 1 or self.candidates < 1 or self.icp_iterations < 1:
            raise ValueError('flips, candidates and icp_iterations must be >= 1')
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
    return height <= ratio * obj.diameter_m


def flipped_poses(T_world_object: np.ndarray, centre_o: np.ndarray, count: int) -> np.ndarray:
    """(count, 4, 4) ``T_world_object`` turned by half a turn about ``count`` horizontal axes
    (180°/count apart) through the object point ``centre_o`` (3,) (its bounding-box centre:
    the turned part occupies the same heights)."""
    T_world_object = np.asarray(T_world_object, np.float64)
    centre_w = transform_points(T_world_object, np.asarray(centre_o, np.float64)[None])[0]
    out = np.tile(T_world_object, (count, 1, 1))
    for k, angle in enumerate(np.pi * np.arange(count) / count):
        R = rotation_about_axis(np.array([np.cos(angle), np.sin(angle), 0.0]), np.pi)
        out[k, :3, :3] = R @ T_world_object[:3, :3]
        out[k, :3, 3] = R @ (T_world_object[:3, 3] - centre_w) + centre_w
    return out


def silhouette(points_o: np.ndarray, T_camera_object: np.ndarray,
               intrinsics: CameraIntrinsics, box: tuple[int, int, int, int],
               spacing_m: float) -> np.ndarray:
    """(h, w) bool silhouette of the model samples ``points_o`` (M, 3) at a pose, in the image
    window ``box`` (x, y, w, h): each sample splatted as a disc as wide as the samples'
    ``spacing_m``."""
    import cv2

    x0, y0, w, h = box
    p = transform_points(T_camera_object, points_o)
    p = p[p[:, 2] > 1e-3]
    mask = np.zeros((h, w), np.uint8)
    if len(p) == 0:
        return mask.astype(bool)
    K = intrinsics.K
    u = np.round(K[0, 0] * p[:, 0] / p[:, 2] + K[0, 2] - x0).astype(int)
    v = np.round(K[1, 1] * p[:, 1] / p[:, 2] + K[1, 2] - y0).astype(int)
    inside = (u >= 0) & (u < w) & (v >= 0) & (v < h)
    mask[v[inside], u[inside]] = 1
    # a closing fills the gaps between the samples without growing the outline
    radius = max(1, int(np.ceil(0.6 * spacing_m * K[0, 0] / float(np.median(p[:, 2])))))
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))
    pad = radius + 1
    closed = cv2.morphologyEx(np.pad(mask, pad), cv2.MORPH_CLOSE, kernel)
    return closed[pad:-pad, pad:-pad].astype(bool)


def edge_distance(rgb: np.ndarray, box: tuple[int, int, int, int]) -> np.ndarray:
    """(h, w) float32 distance (px) to the nearest Canny edge of the colour image in ``box``."""
    import cv2

    x0, y0, w, h = box
    grey = cv2.cvtColor(np.ascontiguousarray(rgb[y0:y0 + h, x0:x0 + w]), cv2.COLOR_RGB2GRAY)
    edges = cv2.Canny(cv2.GaussianBlur(grey, (3, 3), 0), 30, 90)
    return cv2.distanceTransform((edges == 0).astype(np.uint8), cv2.DIST_L2, 3)


def agreement(mask: np.ndarray, distance: np.ndarray, label: np.ndarray, *,
              edge_px: float, iou_weight: float) -> float:
    """Image agreement in [0, 1] of a silhouette ``mask`` with a window's edge ``distance``
    (:func:`edge_distance`) and the localiser's ``label`` mask (same (h, w) shape)."""
    import cv2

    outline = mask & ~cv2.erode(mask.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    edges = float(np.mean(distance[outline] <= edge_px)) if outline.any() else 0.0
    union = np.count_nonzero(mask | label)
    iou = np.count_nonzero(mask & label) / union if union else 0.0
    return (edges + iou_weight * iou) / (1.0 + iou_weight)


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
                     ) -> tuple[float, list[tuple[np.ndarray, float]]]:
        """The fitted pose's depth fitness and the flipped fits that compete with it:
        ``(T_camera_object, fitness)`` best first, at most ``candidates`` of them."""
        from tlessbot_ros.core.pose.cloud import remove_statistical_outliers, voxel_downsample

        p = self.params
        scene, _ = voxel_downsample(np.asarray(points_c, np.float64),
                                    obj.voxel_size_m * self.voxel_scale)
        if len(scene) >= 10:
            scene = scene[remove_statistical_outliers(scene, neighbors=self._sor[0],
                                                      std_ratio=self._sor[1])]
        centre = obj.derived('bbox_centre', lambda: (
            obj.model_points.min(axis=0) + obj.model_points.max(axis=0)).astype(np.float64) / 2)
        T_world_object = T_world_camera @ T_camera_object
        starts = invert_transform(T_world_camera) @ flipped_poses(T_world_object, centre,
                                                                  p.flips)
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
        return own, chosen

    def image_agreement(self, obj: ObjectTemplates, poses: Sequence[np.ndarray],
                        views: Sequence[ViewEvidence]) -> np.ndarray:
        """(K,) mean agreement (:func:`agreement`) of K poses over the views, each view read
        in the window around all the poses' silhouettes."""
        p = self.params
        points = obj.model_points.astype(np.float64)
        spacing = obj.derived('sample_spacing', lambda: _sample_spacing(points))
        scores = np.zeros(len(poses))
        used = 0
        for view in views:
            T = [view.T_view_fit @ np.asarray(T_k, np.float64) for T_k in poses]
            box = _window(points, T, view.intrinsics, margin_px=8)
            if box is None:
                continue
            x0, y0, w, h = box
            distance = edge_distance(view.rgb, box)
            label = np.asarray(view.mask[y0:y0 + h, x0:x0 + w], bool)
            for k, T_k in enumerate(T):
                scores[k] += agreement(silhouette(points, T_k, view.intrinsics, box, spacing),
                                       distance, label, edge_px=p.edge_px,
                                       iou_weight=p.iou_weight)
            used += 1
        return scores / max(used, 1)

    def resolve(self, obj: ObjectTemplates, T_camera_object: np.ndarray, points_c: np.ndarray,
                T_world_camera: np.ndarray, views: Sequence[ViewEvidence]
                ) -> tuple[np.ndarray | None, dict[str, float]]:
        """The flipped pose that replaces the fitted one (None: keep it) and what decided:
        ``{'fitness', 'flip_fitness', 'agreement', 'flip_agreement'}`` (only the depth
        figures when no flipped fit competes)."""
        own, flipped = self.flipped_fits(obj, np.asarray(T_camera_object, np.float64),
                                         points_c, np.asarray(T_world_camera, np.float64))
        info = {'fitness': own}
        if not flipped:
            return None, info
        scores = self.image_agreement(obj, [T_camera_object] + [T for T, _ in flipped], views)
        k = int(np.argmax(scores[1:]))
        info.update(flip_fitness=flipped[k][1], agreement=float(scores[0]),
                    flip_agreement=float(scores[1 + k]))
        if scores[1 + k] > scores[0] + self.params.min_gain:
            return flipped[k][0], info
        return None, info


def _differ(T_a: np.ndarray, T_b: np.ndarray) -> bool:
    from tlessbot_ros.core.pose.candidates import poses_differ
    return poses_differ(T_a, T_b)


def _sample_spacing(points: np.ndarray) -> float:
    """Median distance (m) from a model sample to its nearest neighbour."""
    from scipy.spatial import cKDTree

    distance, _ = cKDTree(points).query(points, k=2)
    return float(np.median(distance[:, 1]))


def _window(points_o: np.ndarray, poses: Sequence[np.ndarray], intrinsics: CameraIntrinsics,
            *, margin_px: int) -> tuple[int, int, int, int] | None:
    """(x, y, w, h) image window around the projected samples at every pose (None: outside
    the image or behind the camera)."""
    K = intrinsics.K
    us, vs = [], []
    for T in poses:
        p = transform_points(T, points_o)
        p = p[p[:, 2] > 1e-3]
        us.append(K[0, 0] * p[:, 0] / p[:, 2] + K[0, 2])
        vs.append(K[1, 1] * p[:, 1] / p[:, 2] + K[1, 2])
    u, v = np.concatenate(us), np.concatenate(vs)
    if len(u) == 0:
        return None
    x0 = int(max(0, np.floor(u.min()) - margin_px))
    y0 = int(max(0, np.floor(v.min()) - margin_px))
    x1 = int(min(intrinsics.width, np.ceil(u.max()) + margin_px + 1))
    y1 = int(min(intrinsics.height, np.ceil(v.max()) + margin_px + 1))
    return (x0, y0, x1 - x0, y1 - y0) if x1 - x0 > 4 and y1 - y0 > 4 else None
