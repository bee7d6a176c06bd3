"""What the flat check works with: its settings, what one camera shows of a part, and which
parts count as flat.

:class:`FlatParams` are the settings of :class:`~tlessbot_ros.core.pose.flat.FlatCheck`;
:class:`ViewEvidence` is one camera's colour, label, depth and table plane around a part;
:func:`is_flat` tells a flat part by its resting height, :func:`is_flat_mesh` by its mesh's
principal extents. This module is light (no Open3D): :mod:`tlessbot_ros.core.params` imports
:class:`FlatParams`.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, cast

import numpy as np

from tlessbot_ros.core.common import CameraIntrinsics, transform_points

if TYPE_CHECKING:
    from tlessbot_ros.core.pose.database import ObjectTemplates


@dataclass(frozen=True)
class FlatParams:
    """Settings of :class:`~tlessbot_ros.core.pose.flat.FlatCheck` (which parts count as flat
    and how their face, yaw and look-alike are checked; docs/flat-parts.md).

    Attributes:
        enabled: check flat parts' face (depth and colour image), yaw and look-alike (image).
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
            either way (0 steps: off); a round part's hole yaw search ends at half the step.
        yaw_min_gain: a new yaw is kept when its agreement gains more than this (0..1).
        depth_tolerance_m: a pixel votes for a pose whose depth error is lower by more than
            this, m (>= 0).
        depth_min_z: the depth vote overturns the pose only with a surplus above this many
            coin-toss deviations (>= 0).
        depth_refit_both: the depth vote compares each turn with the pose refitted to the
            depth as the turn is, not with the pose as it is.
        align_at_1m_m: each pose's rendering is aligned to the view by shifts that cover the
            fit's error in the table plane, this at 1 m, growing with distance², m (>= 0).
        align_min_z: a turned pose wins the aligned vote only with a surplus above this many
            coin-toss deviations (>= 0).
        yaw_turns: a round flat part competes (and its holes' yaw is searched) turned about its
            thin axis by each 1/yaw_turns (or finer) of its listed yaw period (>= 1).
        edge_vote_px: a turn the aligned votes leave open is decided on the image's edges
            inside the outline, within this many pixels (0: not; :mod:`.image_edges`).
        edge_hole_contrast: ... a through hole's rims only where the hole looks unlike the face
            around it: more than this RGB distance from it (0: always).
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
    depth_tolerance_m: float = 0.002
    depth_min_z: float = 2.0
    depth_refit_both: bool = True
    align_at_1m_m: float = 0.010
    align_min_z: float = 3.0
    yaw_turns: int = 6
    edge_vote_px: float = 1.5
    edge_hole_contrast: float = 12.0

    def __post_init__(self) -> None:
        if self.flips < 1 or self.candidates < 1 or self.icp_iterations < 1 or \
                self.min_disputed_px < 1 or self.yaw_steps < 0 or self.yaw_turns < 1:
            raise ValueError('flips, candidates, icp_iterations, min_disputed_px and yaw_turns '
                             'must be >= 1 and yaw_steps >= 0')
        if not 0.5 <= self.min_share <= 1.0 or self.iou_weight < 0 or self.yaw_step_deg <= 0:
            raise ValueError(f'min_share must be in 0.5..1, iou_weight >= 0, yaw_step_deg > 0; '
                             f'got {self.min_share}, {self.iou_weight}, {self.yaw_step_deg}')
        if not 0.0 <= self.flat_ratio <= 1.0 or self.edge_px <= 0 or self.edge_vote_px < 0:
            raise ValueError('flat_ratio must be in [0, 1], edge_px > 0, edge_vote_px >= 0')
        if min(self.depth_tolerance_m, self.depth_min_z, self.align_at_1m_m, self.align_min_z,
               self.edge_hole_contrast) < 0:
            raise ValueError('depth_tolerance_m, depth_min_z, align_at_1m_m, align_min_z and '
                             'edge_hole_contrast must be >= 0')


@dataclass(frozen=True)
class ViewEvidence:
    """What one camera shows of a part: ``rgb`` (H, W, 3) uint8 (None: no colour), ``mask``
    (H, W) bool (the localiser's label of the part; may be empty), its ``intrinsics`` and
    ``T_view_fit`` (4, 4): the transform from the fitted view's optical frame into this one's
    (identity for the fitted view itself); for the aligned votes (:mod:`.flat_align`) its
    ``depth_m`` (H, W) metres, the table ``plane`` (4,) in this camera and ``others`` (H, W)
    bool, the pixels the localiser gave other parts (each None when unknown)."""

    rgb: np.ndarray | None
    mask: np.ndarray
    intrinsics: CameraIntrinsics
    T_view_fit: np.ndarray
    depth_m: np.ndarray | None = None
    plane: np.ndarray | None = None
    others: np.ndarray | None = None


def is_flat(obj: ObjectTemplates, ratio: float) -> bool:
    """Whether ``obj`` rests at most ``ratio`` of its diameter high (its most probable stable
    pose; cached on the object)."""
    height = obj.derived('resting_height', lambda: float(np.ptp(
        transform_points(obj.stable_poses[0], obj.model_points.astype(np.float64))[:, 2])))
    return cast(bool, height <= ratio * obj.diameter_m)


# The template build keeps the mesh of a part whose thinnest principal extent is at most this
# share of its middle one (the depth round ray-casts it): looser than ``flat_ratio``, so that
# the mesh is there whatever ``flat_ratio`` a cell sets.
MESH_FLAT_RATIO = 0.3


def is_flat_mesh(vertices: np.ndarray, ratio: float = MESH_FLAT_RATIO) -> bool:
    """Whether a mesh ((V, 3) vertices) is flat: its thinnest principal extent at most
    ``ratio`` of its middle one."""
    v = np.asarray(vertices, np.float64)
    axes = np.linalg.svd(v - v.mean(axis=0), full_matrices=False)[2]
    extent = np.sort(np.ptp((v - v.mean(axis=0)) @ axes.T, axis=0))
    return bool(extent[0] <= ratio * extent[1])
