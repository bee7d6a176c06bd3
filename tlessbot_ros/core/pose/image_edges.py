"""Box turns compared on the image's edges inside the part's outline (for :mod:`.half_turns`).

A drilled block's box turns (the same box turned about one of its axes) share the outline;
only the holes' rims and the chamfers' creases move. On a smoothed, stereo-like depth those
few millimetres are gone from the depth (a 6 mm hole reads 2 px wide or shut), and the
aligned height votes between the turns fall to a few pixels either way; the colour image
still shows the rims and creases as edges. So each pose's rendered edges
(:func:`~.turns.rendered_edges`: outline, steps, creases) are laid on the image's Canny edges
(:func:`~.silhouette.edge_distance`), each rendering moved by the whole-pixel shift that lays
most of its edges on image edges (the outline brings every turn there alike), and two poses
vote on the rendered edges inside both outlines that only one of them has: a pixel of such an
edge that lies on an image edge votes for the pose that draws it (a one-sided chamfer test,
as in Barrow et al., IJCAI 1977). A missing image edge votes for neither (Canny misses faint
ones alike for every pose).

Poses are ``T_camera_object`` (4, 4) metres in the fitted view's optical frame.
"""
from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import cv2
import numpy as np

if TYPE_CHECKING:
    import open3d as o3d

    from tlessbot_ros.core.pose.flat import FlatParams, ViewEvidence


def edge_votes(scene: o3d.t.geometry.RaycastingScene, poses: Sequence[np.ndarray],
               points_o: np.ndarray, views: Sequence[ViewEvidence], *, align_at_1m_m: float,
               jump_m: float, crease_deg: float, edge_px: float, inner_px: int,
               hole_contrast: float = 0.0) -> np.ndarray:
    """(K, K) int: [i, j] the rendered edge pixels of pose i, over every colour view, inside
    both poses' outlines (holes filled, ``inner_px`` or more from either), more than a pixel
    from every edge of pose j and within ``edge_px`` of an image edge.

    Each pose (of the mesh ``scene``; ``points_o`` the model samples that bound it) is
    rendered (:func:`~.turns.rendered_edges`, ``jump_m``, ``crease_deg``) and moved by the
    whole-pixel shift, within what the fit's error spans (``align_at_1m_m`` at 1 m,
    :func:`~.flat_align.shift_px`), that lays most of its edges on image edges. With
    ``hole_contrast`` > 0, the rims of a pose's through hole that looks like the face around
    it vote for no pose (:func:`_shut_hole_rims`)."""
    return candidate_edge_votes([(scene, P) for P in poses], points_o, views,
                                align_at_1m_m=align_at_1m_m, jump_m=jump_m,
                                crease_deg=crease_deg, edge_px=edge_px, inner_px=inner_px,
                                hole_contrast=hole_contrast)


def candidate_edge_votes(candidates: Sequence[tuple[o3d.t.geometry.RaycastingScene, np.ndarray]],
                         points_o: np.ndarray, views: Sequence[ViewEvidence], *,
                         align_at_1m_m: float, jump_m: float, crease_deg: float, edge_px: float,
                         inner_px: int, hole_contrast: float = 0.0,
                         shut_hole_votes: bool = False) -> np.ndarray:
    """:func:`edge_votes` for candidates that are each a (mesh, pose): a part's look-alikes
    (one hole more, mirrored) at its fitted pose as well as one mesh's turns; ``points_o``
    the model samples that bound them all (look-alikes share their model frame).

    With ``shut_hole_votes`` (and ``hole_contrast`` > 0), each pixel of candidate i's shut
    through hole (:func:`_shut_holes`) with no image edge within two pixels that candidate j
    covers also votes for j: the image shows a plain face where i has a hole, the evidence
    against i that the one-sided rims lack."""
    from tlessbot_ros.core.pose.flat_align import shift_px, shifted
    from tlessbot_ros.core.pose.silhouette import edge_distance, window
    from tlessbot_ros.core.pose.turns import rendered_edges

    count = len(candidates)
    votes = np.zeros((count, count), np.int64)
    for view in views:
        if view.rgb is None:
            continue
        T = [view.T_view_fit @ np.asarray(P, np.float64) for _, P in candidates]
        pad = shift_px(view.intrinsics, points_o, T[0], align_at_1m_m)
        box = window(points_o, T, view.intrinsics, margin_px=pad + inner_px + 4)
        if box is None:
            continue
        x0, y0, w, h = box
        grown = (x0 - pad, y0 - pad, w + 2 * pad, h + 2 * pad)
        on_image = edge_distance(view.rgb, box) <= edge_px
        cut = None if view.others is None else np.asarray(view.others[y0:y0 + h, x0:x0 + w], bool)
        if cut is not None:   # another part's edges vote for no pose of this one
            on_image &= ~cut
        aligned = []
        for (scene, _), T_k in zip(candidates, T):
            edges = rendered_edges(scene, T_k, view.intrinsics, grown, jump_m=jump_m,
                                   crease_deg=crease_deg)
            dx, dy = _best_shift(edges, on_image, pad)
            aligned.append(tuple(shifted(m, pad, dx, dy)
                                 for m in (edges, *_silhouette(scene, T_k, view, grown))))
        near = [cv2.dilate(e.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
                for e, _, _ in aligned]
        # a rim is evidence of a hole where the hole looks unlike its face: a shadow's edge on
        # a closed face can lie where a twin's hole would be (docs/bench/edge-votes-polarity.md)
        holes = [np.zeros((h, w), bool)] * count if hole_contrast <= 0 else _shut_holes(
            [(filled, hit) for _, filled, hit in aligned],
            np.asarray(view.rgb[y0:y0 + h, x0:x0 + w]), cut, hole_contrast)
        shut = [cv2.dilate(m.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
                for m in holes]
        # a shut hole is evidence against its pose only where the image shows no edge by it
        # either: the face's colour next to a rim on an edge is a pose a few pixels off
        quiet = [_without_edges(m, on_image) & (True if cut is None else ~cut)
                 for m in holes] if shut_hole_votes else holes
        for i in range(count):
            for j in range(i + 1, count):
                inside = cv2.erode((aligned[i][1] & aligned[j][1]).astype(np.uint8),
                                   np.ones((2 * inner_px + 1,) * 2, np.uint8)).astype(bool)
                inside &= on_image
                votes[i, j] += np.count_nonzero(aligned[i][0] & inside & ~near[j] & ~shut[i])
                votes[j, i] += np.count_nonzero(aligned[j][0] & inside & ~near[i] & ~shut[j])
                if shut_hole_votes:
                    votes[j, i] += np.count_nonzero(quiet[i] & aligned[j][2])
                    votes[i, j] += np.count_nonzero(quiet[j] & aligned[i][2])
    return votes


def edge_winner(scene: o3d.t.geometry.RaycastingScene, poses: Sequence[np.ndarray],
                points_o: np.ndarray, views: Sequence[ViewEvidence], *, min_z: float,
                **settings: float) -> int:
    """The pose among ``poses`` (the fit first) that wins most duels of :func:`edge_votes`
    (``settings``: its keywords) when it beats the fit by ``min_z`` coin-toss deviations
    (:func:`~.lookalike.clear_margin`); else 0."""
    from tlessbot_ros.core.pose.flat_align import round_robin
    from tlessbot_ros.core.pose.lookalike import clear_margin

    votes = edge_votes(scene, poses, points_o, views, **settings)   # type: ignore[arg-type]
    k = round_robin(votes)
    return k if k > 0 and clear_margin(int(votes[k, 0]), int(votes[0, k]), min_z) else 0


def flat_edge_settings(params: FlatParams) -> dict[str, float]:
    """:func:`edge_votes`' settings for a flat part (``params``' ``edge_vote_px``, its
    alignment): a step of the votes' height tolerance is an edge, a crease of 30° too (the
    turn check's)."""
    return dict(align_at_1m_m=params.align_at_1m_m, jump_m=params.depth_tolerance_m,
                crease_deg=30.0, edge_px=params.edge_vote_px,
                inner_px=1 + int(np.ceil(params.edge_vote_px)),
                hole_contrast=params.edge_hole_contrast)


def _silhouette(scene: o3d.t.geometry.RaycastingScene, T_camera_object: np.ndarray,
                view: ViewEvidence, box: tuple[int, int, int, int]
                ) -> tuple[np.ndarray, np.ndarray]:
    """(filled, hit), each (h, w) bool: the pose's silhouette in ``box`` with its through
    holes filled, and the pixels the mesh covers."""
    from scipy.ndimage import binary_fill_holes

    from tlessbot_ros.core.pose.silhouette import window_depth

    _, _, w, h = box
    _, depth = window_depth(scene, T_camera_object, view.intrinsics, box)
    hit = np.isfinite(depth).reshape(h, w)
    return np.asarray(binary_fill_holes(hit), bool), hit


# the share of a hole's pixels (and those next to it) that must look like the face for the
# hole to count as shut: all but a stray pixel or two of a 4-6 px hole's view through it
_SHUT_SHARE = 0.9


def _shut_holes(silhouettes: Sequence[tuple[np.ndarray, np.ndarray]], rgb: np.ndarray,
                others: np.ndarray | None, contrast: float) -> list[np.ndarray]:
    """Per pose ((filled, hit) (h, w) bool each, aligned, over the (h, w, 3) ``rgb`` window;
    ``others`` the pixels of other parts or None): (h, w) bool, the pixels of its through
    holes that look like the face around it: ``_SHUT_SHARE`` of its pixels and of those next
    to it a colour within ``contrast`` of one of the face's (2-4 pixels out). A hole's rims
    (within two pixels) then vote for no pose.

    A hole shows what lies beyond it or its dark walls, unlike the face it is cut in; a
    shadow's edge across the face shows the face on both sides, lit or shadowed."""
    near, inner = np.ones((9, 9), np.uint8), np.ones((5, 5), np.uint8)
    colour = rgb.astype(np.float32)
    shut = []
    for filled, hit in silhouettes:
        count, labels = cv2.connectedComponents((filled & ~hit).astype(np.uint8), connectivity=8)
        closed = np.zeros(hit.shape, np.uint8)
        for c in range(1, count):
            hole = (labels == c).astype(np.uint8)
            face = hit & cv2.dilate(hole, near).astype(bool) & \
                ~cv2.dilate(hole, inner).astype(bool)
            if others is not None:
                face &= ~others
            if np.count_nonzero(face) < 8:   # too little face seen to tell
                continue
            # a pixel beyond the rendered hole too: a rendering a pixel off the image misses
            # part of a small hole's view through it (a dark part's walls look like its face)
            seen = cv2.dilate(hole, np.ones((3, 3), np.uint8)).astype(bool) & \
                (True if others is None else ~others)
            inside = colour[seen]
            gap = np.linalg.norm(inside[:, None, :] - colour[face][None, :, :], axis=2).min(axis=1)
            if np.count_nonzero(gap <= contrast) >= _SHUT_SHARE * len(inside):
                closed |= hole
        shut.append(closed.astype(bool))
    return shut


def _without_edges(holes: np.ndarray, on_image: np.ndarray) -> np.ndarray:
    """(h, w) bool: the connected ``holes`` ((h, w) bool) with no pixel of ``on_image`` (the
    window's image edges, (h, w) bool) within two pixels."""
    count, labels = cv2.connectedComponents(holes.astype(np.uint8), connectivity=8)
    near = np.ones((5, 5), np.uint8)
    out = np.zeros(holes.shape, bool)
    for c in range(1, count):
        hole = labels == c
        if not (cv2.dilate(hole.astype(np.uint8), near).astype(bool) & on_image).any():
            out |= hole
    return out


def _best_shift(edges: np.ndarray, on_image: np.ndarray, pad: int) -> tuple[int, int]:
    """(dx, dy), |dx|, |dy| <= ``pad``: the shift of the rendered ``edges`` (over the window
    grown by ``pad``) that lays most of them on ``on_image`` (the window's image edges);
    the smallest such shift on a tie."""
    from tlessbot_ros.core.pose.flat_align import shifted

    shifts = sorted(((dx, dy) for dy in range(-pad, pad + 1) for dx in range(-pad, pad + 1)),
                    key=lambda s: abs(s[0]) + abs(s[1]))
    return max(shifts, key=lambda s: np.count_nonzero(shifted(edges, pad, *s) & on_image))


__all__ = ['candidate_edge_votes', 'edge_votes', 'edge_winner', 'flat_edge_settings']
