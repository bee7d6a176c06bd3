"""A part levelled onto the table, turned and moved on the table to lay its edges on the image's.

The resting prior (:func:`~tlessbot_ros.core.pose.resting.settle`) levels a fit onto a stable
pose and refits it in (yaw, x, y) on the depth. A flat part's depth is its top face: it holds
the part's height and tilt, not its turn about the vertical, which only the outline and the
holes' rims show, and those a smoothed (stereo-like) depth blurs over several pixels. The
colour image keeps them sharp. So the levelled pose is refined in the three degrees of freedom
the table leaves it (yaw about the vertical through the part's centre, x, y), by a truncated
chamfer match (Barrow et al., IJCAI 1977; Borgefors, PAMI 1988): the pose's rendered edges
(:func:`~tlessbot_ros.core.pose.turns.rendered_edges`: outline, rims, creases) are sampled once
as 3-D points on the part, and each candidate move scores the mean distance, capped at
``cap_px``, from each projected point to the nearest Canny edge of the image
(:func:`~tlessbot_ros.core.pose.silhouette.edge_distance`), over every colour view. The points
seen at the levelled pose stand for every small move (a turn of a few degrees hides no rim).
A coarse grid over the whole range, then a finer one around its best, keeps the best move.

Poses are ``T_camera_object`` (4, 4) metres in the fitted view's optical frame; the table frame
is ``T_world_camera`` with the table at world z = 0.
"""
from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from tlessbot_ros.core.common import invert_transform, transform_points

if TYPE_CHECKING:
    import open3d as o3d

    from tlessbot_ros.core.pose.flat import ViewEvidence

# the window's margin beyond the part's samples, px: room for the largest move's image shift
_MARGIN_PX = 16


class _EdgeViews:
    """Per colour view: the levelled pose's rendered edge points (in the table frame), the
    transform from the table frame into the view, its camera matrix, and the window's capped
    distance to the image's edges. A view where the edges reach less than ``min_reach_px``
    from the part's centre (90th percentile) is left out: a turn of a few degrees moves them
    by under a pixel there, so the image cannot tell it."""

    def __init__(self, scene: o3d.t.geometry.RaycastingScene, T_world_object: np.ndarray,
                 T_world_fit: np.ndarray, points_o: np.ndarray,
                 views: Sequence[ViewEvidence], *, cap_px: float, jump_m: float,
                 crease_deg: float, min_reach_px: float = 0.0) -> None:
        from tlessbot_ros.core.pose.silhouette import edge_distance, window, window_depth
        from tlessbot_ros.core.pose.turns import rendered_edges

        self.views: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray,
                               tuple[int, int, int, int]]] = []
        T_fit_world = invert_transform(T_world_fit)
        self.reach_px = 0.0
        for view in views:
            if view.rgb is None:
                continue
            T_view_world = view.T_view_fit @ T_fit_world
            T = T_view_world @ T_world_object
            box = window(points_o, [T], view.intrinsics, margin_px=_MARGIN_PX)
            if box is None:
                continue
            edges = rendered_edges(scene, T, view.intrinsics, box, jump_m=jump_m,
                                   crease_deg=crease_deg).reshape(-1)
            rays, depth = window_depth(scene, T, view.intrinsics, box)
            seen = edges & np.isfinite(depth)
            if np.count_nonzero(seen) < 20:
                continue
            reach = _reach_px(seen.reshape(box[3], box[2]), box, T, points_o, view.intrinsics.K)
            self.reach_px = max(self.reach_px, reach)
            if reach < min_reach_px:
                continue
            points_view = rays[seen] * depth[seen, None]
            points_world = transform_points(invert_transform(T_view_world), points_view)
            distance = np.minimum(edge_distance(view.rgb, box), cap_px)
            self.views.append((points_world, T_view_world, view.intrinsics.K, distance, box))
        self.cap = cap_px

    def scores(self, moves: np.ndarray, centre_w: np.ndarray) -> np.ndarray:
        """(M,) mean capped distance (px) of the edge points moved by each of ``moves`` (M, 3)
        (yaw rad about the vertical through ``centre_w``, x m, y m) over every view."""
        total = np.zeros(len(moves))
        count = 0
        cos, sin = np.cos(moves[:, 0]), np.sin(moves[:, 0])
        for points_w, T_view_world, K, distance, (x0, y0, w, h) in self.views:
            rel = points_w[:, :2] - centre_w[:2]
            x = cos[:, None] * rel[:, 0] - sin[:, None] * rel[:, 1] + centre_w[0] + moves[:, 1:2]
            y = sin[:, None] * rel[:, 0] + cos[:, None] * rel[:, 1] + centre_w[1] + moves[:, 2:3]
            moved = np.stack([x, y, np.broadcast_to(points_w[:, 2], x.shape)], axis=-1)
            cam = moved @ T_view_world[:3, :3].T + T_view_world[:3, 3]
            u = np.rint(K[0, 0] * cam[..., 0] / cam[..., 2] + K[0, 2]).astype(np.int64) - x0
            v = np.rint(K[1, 1] * cam[..., 1] / cam[..., 2] + K[1, 2]).astype(np.int64) - y0
            inside = (u >= 0) & (u < w) & (v >= 0) & (v < h)
            found = np.full(u.shape, self.cap)
            found[inside] = distance[v[inside], u[inside]]
            total += found.sum(axis=1)
            count += points_w.shape[0]
        return total / max(count, 1)


def _reach_px(seen: np.ndarray, box: tuple[int, int, int, int], T_view_object: np.ndarray,
              points_o: np.ndarray, K: np.ndarray) -> float:
    """The 90th percentile of the distance (px) from the part's projected centre (its samples'
    mean at ``T_view_object``) to its ``seen`` (h, w) edge pixels in the window ``box``."""
    centre = transform_points(T_view_object, points_o.mean(axis=0, keepdims=True))[0]
    u0 = K[0, 0] * centre[0] / centre[2] + K[0, 2] - box[0]
    v0 = K[1, 1] * centre[1] / centre[2] + K[1, 2] - box[1]
    v, u = np.nonzero(seen)
    return float(np.percentile(np.hypot(u - u0, v - v0), 90))


def _grid(yaw_deg: float, yaw_step_deg: float, shift_m: float, shift_step_m: float,
          centre: np.ndarray) -> np.ndarray:
    """(M, 3) moves (yaw rad, x m, y m) on a grid around ``centre`` (3,)."""
    yaws = np.radians(np.arange(-yaw_deg, yaw_deg + 1e-9, yaw_step_deg))
    shifts = np.arange(-shift_m, shift_m + 1e-12, shift_step_m)
    a, x, y = np.meshgrid(yaws, shifts, shifts, indexing='ij')
    moves: np.ndarray = np.stack([a.ravel(), x.ravel(), y.ravel()], axis=-1) + centre
    return moves


def refine_on_edges(scene: o3d.t.geometry.RaycastingScene, T_camera_object: np.ndarray,
                    T_world_camera: np.ndarray, points_o: np.ndarray,
                    views: Sequence[ViewEvidence], *, max_yaw_deg: float, max_shift_m: float,
                    cap_px: float, jump_m: float, crease_deg: float,
                    min_reach_px: float = 0.0) -> tuple[np.ndarray, dict[str, float]]:
    """The pose of a part resting on the table turned about the vertical (at most
    ``max_yaw_deg``) and moved along the table (at most ``max_shift_m`` in x and y) where its
    edges lie best on the colour views' edges (see the module).

    Args:
        scene: the part's mesh (:func:`~tlessbot_ros.core.pose.flat_turns.mesh_scene`).
        T_camera_object: the levelled pose.
        T_world_camera: the fitted view's table frame (table at world z = 0).
        points_o: (N, 3) the part's model samples (bound its image window).
        views: the part's views (:func:`~tlessbot_ros.core.flat_parts.colour_views`).
        max_yaw_deg, max_shift_m: the range searched.
        cap_px: a rendered edge point farther than this from an image edge counts as this far.
        jump_m, crease_deg: what is a rendered edge (:func:`~.turns.rendered_edges`).
        min_reach_px: a view counts only where the part's edges reach this far from its
            centre in the image (90th percentile, px; 0: every view).

    Returns:
        the refined pose (the given one when no view counts or no move lays the edges
        nearer) and ``edge_yaw_deg``, ``edge_shift_m``, ``edge_before_px``, ``edge_after_px``,
        ``edge_reach_px`` (the largest reach over the views with colour).
    """
    T_wc = np.asarray(T_world_camera, np.float64)
    T_wo = T_wc @ np.asarray(T_camera_object, np.float64)
    edge_views = _EdgeViews(scene, T_wo, T_wc, points_o, views, cap_px=cap_px, jump_m=jump_m,
                            crease_deg=crease_deg, min_reach_px=min_reach_px)
    info = {'edge_yaw_deg': 0.0, 'edge_shift_m': 0.0, 'edge_before_px': 0.0,
            'edge_after_px': 0.0, 'edge_reach_px': edge_views.reach_px}
    if not edge_views.views:
        return np.asarray(T_camera_object, np.float64), info
    centre_w = transform_points(T_wo, points_o.mean(axis=0, keepdims=True))[0]
    zero = np.zeros((1, 3))
    before = float(edge_views.scores(zero, centre_w)[0])
    coarse = _grid(max_yaw_deg, 1.0, max_shift_m, max_shift_m / 3, zero[0])
    best = coarse[int(np.argmin(edge_views.scores(coarse, centre_w)))]
    fine = _grid(0.75, 0.25, max_shift_m / 3, max_shift_m / 12, best)
    fine_scores = edge_views.scores(fine, centre_w)
    k = int(np.argmin(fine_scores))
    info.update(edge_before_px=before, edge_after_px=float(fine_scores[k]))
    if fine_scores[k] >= before:
        return np.asarray(T_camera_object, np.float64), info
    yaw, dx, dy = fine[k]
    info.update(edge_yaw_deg=float(np.degrees(yaw)), edge_shift_m=float(np.hypot(dx, dy)))
    move = np.eye(4)
    move[:2, :2] = [[np.cos(yaw), -np.sin(yaw)], [np.sin(yaw), np.cos(yaw)]]
    move[:3, 3] = centre_w - move[:3, :3] @ centre_w + np.array([dx, dy, 0.0])
    return invert_transform(T_wc) @ move @ T_wo, info


__all__ = ['refine_on_edges']
