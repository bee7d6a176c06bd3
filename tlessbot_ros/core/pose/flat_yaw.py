"""The yaw of a flat part on the table, told by its holes and edges (for
:func:`~tlessbot_ros.core.flat_parts.check_flat`).

A flat part whose outline is round (a disc, a flange: its outline's convex hull covers most of
its circle, :func:`~.flat_turns.outline_frame`) shows the depth and its outline alike at every
turn about its thin axis: only its holes tell the turn, within the yaw period its listed
symmetries give (four bolt holes: 90°). Neither the ICP polish of a turned pose (the depth of
a disc holds no yaw, so the polish lets it drift) nor the silhouette's agreement with the
colour edges (:func:`~.flat_turns.refine_yaw`; a round outline scores alike at every yaw) can
hold it. The aligned score of every view does (:func:`~.flat_align.alignment_score`: the
pixels whose height above the table the posed mesh explains and whose colour it agrees with,
each rendering first aligned to the view by a few pixels): it rises as the rendered holes move
onto the imaged ones, over about a hole's width as seen from the part's axis (a 3.8 mm hole
16 mm out: some ±13°), and is flat elsewhere.

So a search in one dimension (:func:`hole_yaw`): the pose turned about its thin axis, through
its outline's centre, by each 1/``yaw_turns`` of the period, the best of them refined by
halving steps down to half ``yaw_step_deg``. The best turn replaces the pose when it wins the
pixel votes against it (:func:`~.flat_align.pixel_votes`, every view) by a clear margin
(``align_min_z``): where no view shows the holes (a disc standing on its edge), every yaw
explains the view alike and the pose stays. Every other flat part lying on a face gets the
same search within the reach of the silhouette's yaw check (``yaw_steps`` x
``yaw_step_deg``): its outline holds its yaw to a few degrees (the Canny edges' 1.5° steps,
the polish after), its edges and holes on the aligned score to a fraction of one. Each view's
renderings are aligned by one shift, found again about each round's best turn (it makes up
for the fit's error in the table plane, the same for turns about the part's own centre): on
the grid of shifts for the pose, climbed to from the shift the search stands at for a turn a
few degrees off (a few scores instead of some eighty a view).

Poses are ``T_camera_object`` (4, 4) metres in the fitted view's optical frame; turns (4, 4)
in the model frame (applied on the right of a pose).
"""
from __future__ import annotations

from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np

from tlessbot_ros.core.pose.flat_align import (
    aligned_view,
    alignment_score,
    pixel_votes,
    render_heights,
    shift_of,
    shift_px,
    shifted,
)
from tlessbot_ros.core.pose.flat_turns import ROUND_SHARE, outline_frame, turn_about

if TYPE_CHECKING:
    from collections.abc import Sequence

    import open3d as o3d

    from tlessbot_ros.core.pose.database import ObjectTemplates
    from tlessbot_ros.core.pose.flat import FlatParams, ViewEvidence
    from tlessbot_ros.core.pose.flat_align import AlignedView


def hole_yaw_period(obj: ObjectTemplates) -> float:
    """The yaw period (radians) within which :func:`hole_yaw` searches ``obj``: its exact
    (listed) yaw period when its outline is round and the period is not continuous (a disc
    with holes), else 0 (not searched: a plate's outline holds its yaw; a plain disc has
    none)."""
    period = obj.exact_yaw_period()
    return period if period > 0 and _outline(obj)[4] >= ROUND_SHARE else 0.0


def thin_axis(obj: ObjectTemplates) -> np.ndarray:
    """(3,) a flat part's thin axis in its own frame (:func:`~.flat_turns.outline_frame`):
    the axis a round one's holes turn about."""
    return _outline(obj)[3]


def _outline(obj: ObjectTemplates) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray,
                                             float]:
    """:func:`~.flat_turns.outline_frame` of the part's samples (cached on the part)."""
    samples = obj.model_points
    frame: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, float] = obj.derived(
        'outline_frame', lambda: outline_frame(samples.astype(np.float64)))
    return frame


def feature_turn(obj: ObjectTemplates, mesh: o3d.t.geometry.RaycastingScene,
                 period: float) -> float:
    """The turn (radians) about a round flat part's thin axis over which its top view stops
    overlapping itself: where the share of its pixels that a turn changes first reaches 0.9 of
    its median over the period (a hole of width d at a distance R from the axis moves off
    itself after d / R). Within it the aligned score rises towards the true yaw; a coarse
    search with steps this wide lands in it. The top view is ray-cast along the thin axis on
    a grid of 201 x 201 over the part's outline; cached on the part."""
    def build() -> float:
        import cv2

        from tlessbot_ros.core.common import o3d_tensor

        centre, first, second, thin, _ = _outline(obj)
        points = obj.model_points.astype(np.float64) - centre
        radius = float(np.linalg.norm(points - np.outer(points @ thin, thin), axis=1).max())
        n = 201
        u, v = np.meshgrid(*[np.linspace(-radius, radius, n)] * 2)
        origins = centre + u[..., None] * first + v[..., None] * second + radius * thin
        rays = np.concatenate([origins.reshape(-1, 3), np.tile(-thin, (n * n, 1))], axis=1)
        hits = mesh.cast_rays(o3d_tensor(rays.astype(np.float32)))['t_hit'].numpy()
        top = np.isfinite(hits).reshape(n, n).astype(np.uint8)
        turns = np.radians(np.arange(0.5, np.degrees(period) / 2.0 + 1e-9, 0.5))
        changed = np.array([np.count_nonzero(cv2.warpAffine(
            top, cv2.getRotationMatrix2D(((n - 1) / 2, (n - 1) / 2), float(np.degrees(a)),
                                         1.0), (n, n), flags=cv2.INTER_NEAREST) != top)
            for a in turns]) / max(int(np.count_nonzero(top)), 1)
        if not len(turns) or changed.max() <= 0:
            return period
        return float(turns[int(np.argmax(changed >= 0.9 * np.median(changed)))])

    width: float = obj.derived(('feature_turn', round(period, 9)), build)
    return width


class _YawScores:
    """The pooled aligned score of a pose turned about the part's thin axis by any angle, in
    every view with a table plane: each view's window, voting pixels and colour likeness are
    fixed by the turns of the coarse search (their union covers the part at every yaw), so
    the scores of every turn are comparable. Each turn is rendered and aligned once."""

    def __init__(self, mesh: o3d.t.geometry.RaycastingScene, T_camera_object: np.ndarray,
                 obj: ObjectTemplates, views: Sequence[ViewEvidence], coarse: np.ndarray,
                 params: FlatParams) -> None:
        from tlessbot_ros.core.pose.silhouette import window

        self.mesh, self.T0, self.tolerance = mesh, T_camera_object, params.depth_tolerance_m
        self.centre, _, _, self.thin, _ = _outline(obj)
        samples = obj.model_points.astype(np.float64)
        self.views: list[tuple[ViewEvidence, AlignedView]] = []
        for view in views:
            if view.plane is None or (view.rgb is None and view.depth_m is None):
                continue
            poses = [view.T_view_fit @ self.pose(a) for a in coarse]
            pad = shift_px(view.intrinsics, samples, poses[0], params.align_at_1m_m)
            box = window(samples, poses, view.intrinsics, margin_px=pad + 4)
            if box is not None:
                self.views.append((view, aligned_view(
                    [(mesh, T) for T in poses], box, pad, view.intrinsics, view.plane,
                    rgb=view.rgb, depth_m=view.depth_m, others=view.others,
                    tolerance_m=self.tolerance)))
        # per turn (radians): per view its rendering over the grown window
        self.renders: dict[float, list[tuple[np.ndarray, np.ndarray]]] = {
            float(a): [av.renders[k] for _, av in self.views] for k, a in enumerate(coarse)}
        self.shifts: list[tuple[int, int]] = []
        self.own_shifts: dict[float, list[tuple[int, int]]] = {}   # per turn, found once
        self.done: dict[float, float] = {}   # per turn its score at the current shifts
        self.centre_at(0.0)

    def pose(self, angle: float) -> np.ndarray:
        """The pose turned by ``angle`` (radians) about the thin axis."""
        T: np.ndarray = self.T0 @ turn_about(self.thin, angle, self.centre)
        return T

    def rendered(self, angle: float) -> list[tuple[np.ndarray, np.ndarray]]:
        """Per view, the turn's rendering over the view's grown window (each once)."""
        if angle not in self.renders:
            self.renders[angle] = [render_heights(
                self.mesh, view.T_view_fit @ self.pose(angle), view.intrinsics,
                (av.box[0] - av.pad, av.box[1] - av.pad, av.box[2] + 2 * av.pad,
                 av.box[3] + 2 * av.pad), np.asarray(view.plane)) for view, av in self.views]
        return self.renders[angle]

    def centre_at(self, angle: float) -> None:
        """Align every view's renderings by the shift that suits the turn by ``angle``
        (:func:`~.flat_align.shift_of`): it makes up for the fit's error in the table plane,
        which is about the same for every turn near it about the part's own centre."""
        if self.shift(angle) != self.shifts:
            self.shifts, self.done = self.shift(angle), {}

    def score(self, angle: float) -> float:
        """The turn's aligned score summed over the views, at the views' current shifts."""
        if angle not in self.done:
            total = 0.0
            for (_, av), (dx, dy), (hit, height) in zip(self.views, self.shifts,
                                                         self.rendered(angle)):
                total += alignment_score(av, shifted(hit, av.pad, dx, dy),
                                         shifted(height, av.pad, dx, dy), self.tolerance)
            self.done[angle] = total
        return self.done[angle]

    def votes(self, angle: float) -> tuple[int, int]:
        """(pixels that the turn by ``angle`` explains better than the pose, pixels the pose
        explains better), every view, each rendering at its own best shift."""
        favour = against = 0
        for k, (_, av) in enumerate(self.views):
            (hit, height), (own_hit, own_height) = self.rendered(angle)[k], self.rendered(0.0)[k]
            (dx, dy), (ox, oy) = self.shift(angle)[k], self.shift(0.0)[k]
            f, a = pixel_votes(av, (shifted(hit, av.pad, dx, dy), shifted(height, av.pad, dx, dy)),
                               (shifted(own_hit, av.pad, ox, oy),
                                shifted(own_height, av.pad, ox, oy)), self.tolerance)
            favour, against = favour + f, against + a
        return favour, against

    def shift(self, angle: float) -> list[tuple[int, int]]:
        """Per view, the turn's own best shift (:func:`~.flat_align.shift_of`; each once):
        the pose's found on the grid, another turn's climbed to from the shifts the search
        stands at (the fit's error in the table plane, shared by turns about the part's own
        centre a few degrees apart)."""
        if angle not in self.own_shifts:
            near: list[tuple[int, int] | None] = [*self.shifts] or [None] * len(self.views)
            self.own_shifts[angle] = [
                shift_of(replace(av, renders=[render]), 0, self.tolerance, start)
                for (_, av), render, start in zip(self.views, self.rendered(angle), near)]
        return self.own_shifts[angle]


def hole_yaw(obj: ObjectTemplates, mesh: o3d.t.geometry.RaycastingScene,
             T_camera_object: np.ndarray, views: Sequence[ViewEvidence], params: FlatParams,
             normal_c: np.ndarray | None = None) -> tuple[np.ndarray, float]:
    """A flat part's pose turned about its thin axis by the angle whose aligned score is
    best: for a round part within its yaw period (:func:`hole_yaw_period`; coarse steps of
    1/``yaw_turns`` of the period), for another within ``yaw_steps`` x ``yaw_step_deg``
    either way (its outline holds the yaw that far; coarse steps of half that) and only
    lying on a face (its thin axis nearer the table's normal ``normal_c``, camera frame, than
    square to it: a part standing on an edge turned about its thin axis would leave the
    table), then halving steps down to half ``yaw_step_deg``; taken when that turn wins the
    pixel votes against the pose by a clear margin (``align_min_z``). Returns (the pose, the
    turn in degrees; 0 when kept)."""
    from tlessbot_ros.core.pose.lookalike import clear_margin

    T0 = np.asarray(T_camera_object, np.float64)
    if params.yaw_steps < 1:
        return T0, 0.0
    period = hole_yaw_period(obj)
    if period > 0:
        # coarse steps no wider than the turn over which the holes stop overlapping themselves
        steps = max(params.yaw_turns, 2, int(np.ceil(period / feature_turn(obj, mesh, period))))
        coarse = period * np.arange(steps) / steps
        step = period / steps / 2.0
    else:
        thin = T0[:3, :3] @ _outline(obj)[3]
        if normal_c is None or abs(float(thin @ normal_c)) < np.sqrt(0.5) * np.linalg.norm(
                normal_c):
            return T0, 0.0
        period = 2.0 * np.pi
        step = np.radians(params.yaw_steps * params.yaw_step_deg) / 2.0
        coarse = np.array([0.0, -step, step])
        step /= 2.0
    search = _YawScores(mesh, T0, obj, views, coarse, params)
    if not search.views:
        return T0, 0.0
    best = max((float(a) for a in coarse), key=search.score)
    while step >= np.radians(params.yaw_step_deg) / 2.0:
        search.centre_at(best)
        best = max((best, best - step, best + step), key=search.score)   # a tie keeps it
        step /= 2.0
    nearest = float((best + period / 2.0) % period - period / 2.0)   # the same, nearest T0
    if nearest == 0.0 or not clear_margin(*search.votes(best), params.align_min_z):
        return T0, 0.0
    return search.pose(nearest), float(np.degrees(nearest))


__all__ = ['feature_turn', 'hole_yaw', 'hole_yaw_period', 'thin_axis']
