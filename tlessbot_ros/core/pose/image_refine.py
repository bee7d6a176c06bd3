"""Poses refined on the image before their aligned votes (for :mod:`.half_turns`).

A drilled block lying on a side shows the top camera a face without holes; the side camera
sees the holes' ends at a slant, a few tens of pixels. The fit and its box turn (the same box,
turned about one of its axes) share the fit's own error, a degree or two and a millimetre, and
the aligned votes between them (:func:`~.flat_align.view_votes`) then weigh holes that neither
rendering puts over the imaged ones: the right turn gets as few votes as the wrong one, while
the exact true pose wins them clearly. The whole-pixel shifts of the votes make up for the
fit's error in the table plane, not for its rotation.

So the fit is first refined on what every view shows (:func:`refine_on_image`): turned
about the part's centre by small steps about three axes, each turn keeping the part resting on
the table (the image score rises along a tilt and the lift it brings, not along either alone),
and moved by fractions of a pixel; each pose rendered into every view and aligned by its own
whole-pixel shift (:func:`~.flat_align.shift_of`), a step kept while it raises the aligned
score summed over the views (:func:`~.flat_align.alignment_score`: the pixels whose height
above the table the rendering explains and whose colour it agrees with), a coordinate ascent
with halving steps (a pattern search, Hooke & Jeeves, JACM 1961). The box's outline, hundreds
of pixels, brings the fit onto the imaged box; each turn starts there (the outline is the
same) and its finest steps lay its holes over the imaged ones, as the wrong turns' cannot. The
refined poses then vote inside both outlines only: there they differ by their features, on the
outline by what each refinement left.

Poses are ``T_camera_object`` (4, 4) metres in the fitted view's optical frame.
"""
from __future__ import annotations

from collections.abc import Sequence
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
from tlessbot_ros.core.pose.flat_turns import turn_about

if TYPE_CHECKING:
    import open3d as o3d

    from tlessbot_ros.core.pose.flat import ViewEvidence
    from tlessbot_ros.core.pose.flat_align import AlignedView


class _ImageScore:
    """The aligned score of any pose near the given ones, summed over every view with a table
    plane: each view's window, voting pixels and colour likeness are fixed by the given poses
    (so the scores of poses near them are comparable); each pose is rendered over the grown
    window and aligned by the best whole-pixel shift climbed to from ``start`` (per view)."""

    def __init__(self, mesh: o3d.t.geometry.RaycastingScene, poses: Sequence[np.ndarray],
                 points_o: np.ndarray, views: Sequence[ViewEvidence], *, align_at_1m_m: float,
                 tolerance_m: float, margin_px: int) -> None:
        from tlessbot_ros.core.pose.silhouette import window

        self.mesh, self.tolerance = mesh, tolerance_m
        self.views: list[tuple[ViewEvidence, AlignedView]] = []
        for view in views:
            if view.plane is None or (view.rgb is None and view.depth_m is None):
                continue
            T = [view.T_view_fit @ np.asarray(P, np.float64) for P in poses]
            pad = shift_px(view.intrinsics, points_o, T[0], align_at_1m_m)
            box = window(points_o, T, view.intrinsics, margin_px=pad + 4 + margin_px)
            if box is not None:
                self.views.append((view, aligned_view(
                    [(mesh, P) for P in T], box, pad, view.intrinsics, view.plane,
                    rgb=view.rgb, depth_m=view.depth_m, others=view.others,
                    tolerance_m=tolerance_m)))

    def rendered(self, T: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
        """Per view, the pose's (hit, height) over the view's grown window."""
        out = []
        for view, av in self.views:
            x0, y0, w, h = av.box
            grown = (x0 - av.pad, y0 - av.pad, w + 2 * av.pad, h + 2 * av.pad)
            out.append(render_heights(self.mesh, view.T_view_fit @ T, view.intrinsics, grown,
                                      np.asarray(view.plane)))
        return out

    def score(self, T: np.ndarray, start: Sequence[tuple[int, int] | None]
              ) -> tuple[float, list[tuple[int, int]]]:
        """(the pose's aligned score summed over the views, per view its shift)."""
        total, shifts = 0.0, []
        for (_, av), render, near in zip(self.views, self.rendered(T), start):
            dx, dy = shift_of(replace(av, renders=[render]), 0, self.tolerance, near)
            hit, height = render
            total += alignment_score(av, shifted(hit, av.pad, dx, dy),
                                     shifted(height, av.pad, dx, dy), self.tolerance)
            shifts.append((dx, dy))
        return total, shifts

    def votes(self, poses: Sequence[tuple[np.ndarray, Sequence[tuple[int, int]]]],
              edge_px: int) -> np.ndarray:
        """(K, K) int: [i, j] the pixels of every view that pose i explains better than pose
        j (:func:`~.flat_align.pixel_votes`), each pose (``T``, per view its shift) rendered
        at its shift, on the pixels inside both outlines (holes filled) and ``edge_px`` or
        more from either."""
        import cv2
        from scipy.ndimage import binary_fill_holes

        count = len(poses)
        votes = np.zeros((count, count), np.int64)
        renders = [self.rendered(T) for T, _ in poses]
        for v, (_, av) in enumerate(self.views):
            aligned = [(shifted(renders[k][v][0], av.pad, *poses[k][1][v]),
                        shifted(renders[k][v][1], av.pad, *poses[k][1][v]))
                       for k in range(count)]
            filled = [binary_fill_holes(hit) for hit, _ in aligned]
            for i in range(count):
                for j in range(i + 1, count):
                    inside = cv2.erode((filled[i] & filled[j]).astype(np.uint8),
                                       np.ones((2 * edge_px + 1,) * 2, np.uint8)).astype(bool)
                    favour, against = pixel_votes(replace(av, region=av.region & inside),
                                                  aligned[i], aligned[j], self.tolerance)
                    votes[i, j] += favour
                    votes[j, i] += against
        return votes


def refine_on_image(mesh: o3d.t.geometry.RaycastingScene, poses: Sequence[np.ndarray],
                    points_o: np.ndarray, centre_o: np.ndarray, views: Sequence[ViewEvidence],
                    *, align_at_1m_m: float, tolerance_m: float, step_deg: float,
                    min_step_deg: float, max_deg: float, max_move_m: float, edge_px: int
                    ) -> tuple[list[np.ndarray], np.ndarray | None]:
    """The first of ``poses`` (of the mesh ``mesh``; ``points_o`` the model samples that
    bound them) moved where its aligned score over every view is best: turned about
    ``centre_o`` (model frame) by ``step_deg`` about each of the fitted view's three axes,
    either way, and moved along each by the arc that turn spans at the part's radius (a
    fraction of a pixel: the whole-pixel shifts leave that much); the best of these steps
    taken while it raises the score and the pose stays within ``max_deg`` and ``max_move_m`` of
    where it began, then halved steps down to ``min_step_deg``. The others are turns of the
    first (``poses[k] = poses[0] @ S_k``): each starts from the first's refinement turned by
    ``S_k`` (the error that refinement removed is theirs too: the box's outline is theirs)
    and is refined by steps of ``min_step_deg`` only, which lay its own features (holes) over
    the imaged ones. A turn keeps the part's lowest sample at its height above the fitted
    view's table (:func:`_steps`). Each rendering is aligned by its own whole-pixel shift
    (``align_at_1m_m``), heights compared within ``tolerance_m``.

    Returns the refined poses and their (K, K) pixel votes, [i, j] the pixels of every view
    that pose i explains better than pose j (:func:`~.flat_align.pixel_votes`), each rendering
    at the shift its refinement found (a shift found again may end a pixel off), on the
    pixels inside both outlines and ``edge_px`` or more from either: the turns share the
    box's outline, where the poses differ only by what their refinements left; (the poses,
    None) where no view has a table plane."""
    from tlessbot_ros.core.common import rotation_angle_deg

    poses = [np.asarray(T, np.float64) for T in poses]
    extent = float(np.ptp(points_o, axis=0).max())
    depth = float(np.median(points_o @ poses[0][2, :3] + poses[0][2, 3]))
    focal = max((float(view.intrinsics.K[0, 0]) for view in views), default=0.0)
    # the window holds every pose a refinement may reach
    reach = int(np.ceil(focal * (np.radians(max_deg) * extent / 2 + max_move_m)
                        / max(depth, 1e-3)))
    scores = _ImageScore(mesh, poses, points_o, views, align_at_1m_m=align_at_1m_m,
                         tolerance_m=tolerance_m, margin_px=reach)
    if not scores.views:
        return poses, None
    out: list[tuple[np.ndarray, list[tuple[int, int]]]] = []
    support = _support(points_o, views)
    for T0 in poses:
        step = step_deg
        if out:   # a turn of the first pose starts where the first one's refinement ended
            T0, step = out[0][0] @ np.linalg.inv(poses[0]) @ T0, min_step_deg
        best, (value, shifts) = T0, scores.score(T0, [None] * len(scores.views))
        centre0 = T0[:3, :3] @ centre_o + T0[:3, 3]
        while step >= min_step_deg:
            while True:
                tried = [T for T in _steps(best, centre_o, np.radians(step), extent / 2, support)
                         if rotation_angle_deg(T[:3, :3], T0[:3, :3]) <= max_deg and
                         np.linalg.norm(T[:3, :3] @ centre_o + T[:3, 3] - centre0)
                         <= max_move_m]
                found = [(scores.score(T, shifts), T) for T in tried]
                top = max(range(len(found)), key=lambda k: found[k][0][0], default=None)
                if top is None or found[top][0][0] <= value:
                    break
                (value, shifts), best = found[top]
            step /= 2.0
        out.append((best, shifts))
    return [T for T, _ in out], scores.votes(out, edge_px)


def _support(points_o: np.ndarray, views: Sequence[ViewEvidence]
             ) -> tuple[np.ndarray, np.ndarray] | None:
    """(some 500 model samples, the table plane (4,) in the fitted view) when the fitted view
    (``T_view_fit`` the identity) has a table plane, else None."""
    for view in views:
        if view.plane is not None and np.allclose(view.T_view_fit, np.eye(4)):
            return points_o[::max(1, len(points_o) // 500)], np.asarray(view.plane, np.float64)
    return None


def _lowest(samples: np.ndarray, T: np.ndarray, normal: np.ndarray) -> float:
    """The least height along ``normal`` of the model ``samples`` at the pose ``T``."""
    return float(np.min(samples @ (T[:3, :3].T @ normal)) + T[:3, 3] @ normal)


def _steps(T: np.ndarray, centre_o: np.ndarray, angle_rad: float, radius_m: float,
           support: tuple[np.ndarray, np.ndarray] | None) -> list[np.ndarray]:
    """The pose turned by ``angle_rad`` about each camera axis through ``centre_o``, either
    way, and moved along each by the arc ``angle_rad`` x ``radius_m``, either way (12). With
    ``support`` (model samples, the table plane), each turn is also moved along the table's
    normal to keep the lowest sample at its height: a part resting on the table rests on it
    turned too, and a tilt about its centre alone would sink or lift it (the image score
    rises along the coupled move, not along either alone)."""
    out = []
    for axis in np.eye(3):
        for sign in (1.0, -1.0):
            turned = turn_about(axis, sign * angle_rad, T[:3, :3] @ centre_o + T[:3, 3]) @ T
            if support is not None:
                samples, plane = support
                normal = plane[:3]
                turned[:3, 3] += (_lowest(samples, T, normal)
                                  - _lowest(samples, turned, normal)) * normal
            out.append(turned)
            moved = T.copy()
            moved[:3, 3] += sign * angle_rad * radius_m * axis
            out.append(moved)
    return out


__all__ = ['refine_on_image']
