"""Half turns of a fitted part that its depth may not rule out, decided by every view's aligned
height and colour votes.

A drilled block turned over about any of its axes shows the camera the same box: only its
holes, 6 mm wide, move (the turn check's edges, :mod:`.turns`, see too few of them to decide).
A bracket whose two legs differ by a quarter fits one view's depth nearly as well turned about
the diagonal between them, and the fit's ICP can end there (a local minimum that the true pose
beats on the depth by 0.05-0.06 of its points). Both are half turns that map a large share of
the part's surface onto itself: :func:`self_half_turns` lists them once per part, about the
model frame's axes, the surface's principal axes and the diagonals between any two of those,
each through the point that maps the turned surface best onto itself (a few steps of
translation-only ICP of the surface samples onto themselves, as Besl & McKay, PAMI 1992). A
turn is kept when at least ``min_share`` of the turned samples lie within the part's voxel (the
fit's own correspondence scale) of the surface (a view sees about half of a part, so a turn
that puts less back cannot fit one) and it is no exact symmetry (those look the same).

:func:`choose_half_turn` turns the fitted pose by each, refits each to the ROI cloud, and lets
the turned fits that explain the depth about as well compete with the fit on the aligned
height and colour votes of every view (:meth:`~.flat.FlatCheck.aligned_winner`, the flat
parts' vote: each rendering aligned by a few pixels, compared pixel by pixel, a clear margin).
A turn that maps the part's hull onto itself competes first turned as it is, the fit refined
on the image before (:mod:`.image_refine`), and where the heights leave that round open, on
the image's edges inside the outline (:mod:`.image_edges`).

Poses are ``T_camera_object`` (4, 4) metres, optical frame; turns (4, 4) in the model frame.
"""
from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, cast

import numpy as np

from tlessbot_ros.core.common import rotation_about_axis
from tlessbot_ros.core.pose.fallback import turn_axes

if TYPE_CHECKING:
    import open3d as o3d

    from tlessbot_ros.core.pose.database import ObjectTemplates
    from tlessbot_ros.core.pose.flat import FlatCheck, ViewEvidence
    from tlessbot_ros.core.pose.turns import TurnParams


def half_turn_axes(points: np.ndarray) -> list[np.ndarray]:
    """The axes half turns are tried about: :func:`~.fallback.turn_axes` (the model frame's and
    the principal axes) and the diagonals (a ± b) / √2 of any two of them, none within 5° of
    another (unit vectors)."""
    base = turn_axes(points)
    axes = list(base)
    cos5 = np.cos(np.radians(5.0))
    for i, a in enumerate(base):
        for b in base[i + 1:]:
            for sign in (1.0, -1.0):
                v = a + sign * b
                v = v / np.linalg.norm(v)
                if all(abs(v @ u) < cos5 for u in axes):
                    axes.append(v)
    return axes


def self_half_turns(obj: ObjectTemplates, *, min_share: float = 0.4,
                    exact_ratio: float = 3.0, exact_quantile: float = 0.98,
                    steps: int = 6) -> np.ndarray:
    """(K, 4, 4) the half turns about :func:`half_turn_axes` that map at least ``min_share`` of
    the part's surface samples within its voxel of the surface, and are no exact symmetry
    (the ``exact_quantile`` of the distances at most ``exact_ratio`` sample spacings, as
    :func:`~.turns.near_turns` judges it); each through the point found by ``steps`` steps of
    translation-only ICP of the turned samples onto the samples (median offset). Cached."""
    from tlessbot_ros.core.pose.turns import surface_centre

    key = ('self_half_turns', float(min_share), float(exact_ratio), float(exact_quantile),
           int(steps))

    def build() -> np.ndarray:
        model = obj.model_points.astype(np.float64)
        tree = obj.model_tree()
        sub = model[::max(1, len(model) // 1500)]
        spacing = float(np.median(tree.query(sub, k=2)[0][:, 1]))
        centre = surface_centre(obj)
        kept = []
        for axis in half_turn_axes(model):
            S = np.eye(4)
            S[:3, :3] = rotation_about_axis(axis, np.pi)
            S[:3, 3] = centre - S[:3, :3] @ centre
            for _ in range(steps):
                moved = sub @ S[:3, :3].T + S[:3, 3]
                S[:3, 3] += np.median(model[tree.query(moved)[1]] - moved, axis=0)
            d = tree.query(sub @ S[:3, :3].T + S[:3, 3])[0]
            if np.quantile(d, exact_quantile) <= exact_ratio * spacing:
                continue   # an exact symmetry: it looks the same
            if np.mean(d <= obj.voxel_size_m) >= min_share:
                kept.append(S)
        return np.array(kept).reshape(-1, 4, 4)
    return cast(np.ndarray, obj.derived(key, build))


def choose_half_turn(check: FlatCheck, obj: ObjectTemplates, T_camera_object: np.ndarray,
                     scene_c: np.ndarray, views: Sequence[ViewEvidence], params: TurnParams
                     ) -> tuple[np.ndarray, dict[str, float]]:
    """The fitted pose or the refitted half turn of it (:func:`self_half_turns`) that the
    aligned votes of every view choose by a clear margin.

    Each turned pose is refitted to the ROI cloud ``scene_c`` (``half_icp_iterations`` steps of
    the pose stage's ICP); the ``half_candidates`` best by depth fitness among those at most
    ``max_fitness_drop`` below the fitted pose's, each a distinct pose, compete with it
    (:meth:`~.flat.FlatCheck.aligned_winner`: ``check``'s ``align_at_1m_m``,
    ``depth_tolerance_m`` and ``align_min_z``).

    Returns:
        the pose and what decided: ``half_turns`` that competed, ``half_fitness`` of the
        fitted pose, ``half_winner`` (0: the fitted pose) and ``half_decided``.
    """
    from tlessbot_ros.core.pose.candidates import poses_differ
    from tlessbot_ros.core.pose.flat_turns import mesh_scene

    T0 = np.asarray(T_camera_object, np.float64)
    info = {'half_turns': 0.0, 'half_fitness': 0.0, 'half_winner': 0.0, 'half_decided': 0.0}
    mesh = mesh_scene(obj)
    turns = self_half_turns(obj, min_share=params.half_min_share,
                            exact_ratio=params.exact_ratio, exact_quantile=params.exact_quantile)
    if mesh is None or not len(turns) or not any(v.plane is not None for v in views):
        return T0, info
    refiner = check.refiner
    kept = box_turns(obj, turns, params)
    T, box_info = _box_turn(check, obj, mesh, T0, turns[kept], scene_c, views, params)
    info.update(box_info)
    if T is not None or kept.all():
        return T0 if T is None else T, info
    turned = refiner.icp_batch(scene_c, obj, T0 @ turns[~kept],
                               iterations=params.half_icp_iterations)
    # a refit that ends on a box turn of the fit is that turn, which the fair duel judged
    turned = np.array([T for T in turned if all(poses_differ(T, T0 @ S) for S in turns[kept])]
                      ).reshape(-1, 4, 4)
    fitness = refiner.grid_fitness(np.concatenate([T0[None], turned]), scene_c, obj)
    poses = _distinct_by_fitness([T0], list(turned), fitness[1:], fitness[0], params)
    info.update(half_turns=float(len(poses) - 1), half_fitness=float(fitness[0]))
    if len(poses) < 2:
        return T0, info
    found: dict[str, float] = {}
    k = check.aligned_winner(obj, [mesh] * len(poses), poses, views, found)
    info.update(half_winner=float(k), half_decided=found.get('align_decided', 0.0))
    return poses[k], info


def box_turns(obj: ObjectTemplates, turns: np.ndarray, params: TurnParams) -> np.ndarray:
    """(K,) bool: which of the half ``turns`` are near-symmetric turns of the part
    (:func:`~.turns.near_turns`, within half a step: most of its surface, its hull, maps onto
    itself: a drilled block turned about one of its box's axes)."""
    from tlessbot_ros.core.common import rotation_angle_deg
    from tlessbot_ros.core.pose.turns import near_turns

    near = near_turns(obj, step_deg=params.step_deg, min_turn_deg=params.min_turn_deg,
                      near_ratio=params.near_ratio, exact_ratio=params.exact_ratio,
                      exact_quantile=params.exact_quantile)
    return np.array([any(rotation_angle_deg(S[:3, :3], N[:3, :3]) <= params.step_deg / 2
                         for N in near) for S in turns], bool).reshape(len(turns))


def _box_turn(check: FlatCheck, obj: ObjectTemplates, mesh: o3d.t.geometry.RaycastingScene,
              T0: np.ndarray, turns: np.ndarray, scene_c: np.ndarray,
              views: Sequence[ViewEvidence], params: TurnParams
              ) -> tuple[np.ndarray | None, dict[str, float]]:
    """The fit turned as it is by the one of its :func:`box_turns` that wins the aligned votes
    against the other turns and beats the fit by a clear margin (None: none does), and what
    decided (``box_turns`` that competed, ``box_winner``).

    Such a turn fits the depth where the fit does (the part's hull maps onto itself), so
    turned as it is it keeps the fit's own placement error and the duel sees only the features
    that tell the two apart: a drilled block's 6 mm holes, which an error of a refit, as large
    as their displacement, would drown. The fit is the pose to beat; the other turns, each as
    wrong as the fit where another wins, need only lose their duels (:func:`_box_winner`: on
    the poses refined on the image first). The winner is then refitted to the depth
    (``half_icp_iterations`` ICP steps), as a fit is: the shared error served the duel only."""
    info = {'box_turns': 0.0, 'box_winner': 0.0}
    if not len(turns):
        return None, info
    exact = [T0 @ S for S in turns]
    fitness = check.refiner.grid_fitness(np.stack([T0, *exact]), scene_c, obj)
    poses = _distinct_by_fitness([T0], exact, fitness[1:], fitness[0], params)
    info['box_turns'] = float(len(poses) - 1)
    if len(poses) < 2:
        return None, info
    k, decided = _box_winner(check, obj, mesh, poses, views, params)
    if k == 0 or not decided:
        return None, info
    info.update(box_winner=float(k), half_winner=float(k), half_decided=1.0)
    return check.refiner.icp_batch(scene_c, obj, poses[k][None],
                                   iterations=params.half_icp_iterations)[0], info


def _box_winner(check: FlatCheck, obj: ObjectTemplates, mesh: o3d.t.geometry.RaycastingScene,
                poses: list[np.ndarray], views: Sequence[ViewEvidence], params: TurnParams
                ) -> tuple[int, bool]:
    """(the index of the pose among ``poses`` (the fit first, then its box turns as they
    are) that wins most of the aligned duels, whether it beats the fit by a clear margin).

    First :meth:`~.flat.FlatCheck.aligned_winner` of the poses as they are. Where that names
    no turn clearly and the fit does not beat every turn clearly either, with
    ``box_refine_deg``, and where every turn keeps the part's hull within
    ``box_refine_max_m`` (:func:`hull_moved_m`), the poses are refined on every view's image
    (:func:`~.image_refine.refine_on_image`) and the duels of the refined poses decide: the
    fit's own error of a degree or two, shared by its turns, leaves the holes of the right
    turn beside the imaged ones, and their few votes fall under the margin. Where the
    refined round is open too, the poses as they are vote on the image's edges inside the
    outline (:func:`_edge_winner`); where no edge names a turn either, with
    ``box_agreed_turn``, a turn that wins every duel of both rounds, the poses as they are and
    refined, is taken (:func:`_agreed_turn`): the two rounds agree on a direction that neither
    shows by the margin."""
    from tlessbot_ros.core.pose.flat_align import round_robin
    from tlessbot_ros.core.pose.image_refine import refine_on_image
    from tlessbot_ros.core.pose.lookalike import clear_margin
    from tlessbot_ros.core.pose.turns import surface_centre

    p = check.params
    found: dict[str, float] = {}
    k = check.aligned_winner(obj, [mesh] * len(poses), poses, views, found, rivals=[0])
    named = k if k > 0 and found.get('align_decided') else 0
    T0_inverse = np.linalg.inv(poses[0])
    if params.box_refine_deg <= 0 or any(hull_moved_m(obj, T0_inverse @ T) >
                                         params.box_refine_max_m for T in poses[1:]):
        # the refined poses vote inside both outlines only: a turn that moves the part's hull
        # (a screw end for end: its head) moves the outline, the evidence that vote leaves out
        return k, bool(found.get('align_decided'))
    votes = check.ranked[1] if check.ranked is not None else None
    if votes is not None and len(votes) == len(poses) and all(
            clear_margin(int(votes[0, j]), int(votes[j, 0]), p.align_min_z)
            for j in range(1, len(poses))):
        return 0, True   # the views rule every turn out as they are
    _, refined = refine_on_image(mesh, poses, obj.model_points.astype(np.float64),
                                 surface_centre(obj), views, align_at_1m_m=p.align_at_1m_m,
                                 tolerance_m=p.depth_tolerance_m,
                                 step_deg=params.box_refine_deg,
                                 min_step_deg=params.box_refine_min_deg,
                                 max_deg=params.box_refine_max_deg,
                                 max_move_m=params.box_refine_max_m,
                                 edge_px=params.box_edge_px)
    if refined is None:
        return k, bool(found.get('align_decided'))
    k = round_robin(refined)
    # a turn that the poses as they are name clearly stands when the refined ones agree
    if k > 0 and (k == named or clear_margin(int(refined[k, 0]), int(refined[0, k]),
                                             p.align_min_z)):
        return k, True
    if all(clear_margin(int(refined[0, j]), int(refined[j, 0]), p.align_min_z)
           for j in range(1, len(poses))):
        return 0, True   # the refined views rule every turn out
    # the poses as they are: a turn refined on the image lays its rims over whatever edges it
    # meets, and would win on them (docs/bench/smoothed-turns.md)
    smoothed = measures_smoothed(check, obj, mesh, poses[0], views) if \
        params.box_agreed_turn or (params.box_image_edges and params.box_edges_smoothed_only) \
        else False
    edges = _edge_winner(check, obj, mesh, poses, views, params, smoothed)
    if edges is not None:
        return edges
    agreed = votes is not None and len(votes) == len(poses) and \
        _agreed_turn(obj, mesh, poses, votes, refined, k, views, params, smoothed)
    return k, agreed


def _agreed_turn(obj: ObjectTemplates, mesh: o3d.t.geometry.RaycastingScene,
                 poses: list[np.ndarray], votes: np.ndarray, refined: np.ndarray, k: int,
                 views: Sequence[ViewEvidence], params: TurnParams, smoothed: bool) -> bool:
    """Whether ``box_agreed_turn`` takes turn ``k`` of ``poses`` (the fit first): it wins every
    duel both as the poses are (``votes``) and refined (``refined``, each (N, N) [i, j]:
    pixels for i against j), the depth at the fit measures per-pixel (``smoothed`` False) and
    the turn changes at least ``box_agreed_min_px`` pixels of the fit (:func:`turn_seen_px`).

    Each round falls short of the margin by the fit's own error; two that name one turn duel by
    duel agree on a direction neither shows clearly. A smoothed depth shows no holes, and its
    two rounds agree by chance; so do the rounds of a turn the rig hardly sees (a nut's chamfers
    of half a millimetre), whatever the depth."""
    if not params.box_agreed_turn or k <= 0 or smoothed or not _wins_every_duel(votes, k) or \
            not _wins_every_duel(refined, k):
        return False
    return turn_seen_px(obj, mesh, poses[0], poses[k], views) >= params.box_agreed_min_px


def turn_seen_px(obj: ObjectTemplates, mesh: o3d.t.geometry.RaycastingScene, T_a: np.ndarray,
                 T_b: np.ndarray, views: Sequence[ViewEvidence]) -> int:
    """The pixels, summed over the ``views`` with a table plane, that tell the part (``mesh``,
    model frame) at pose ``T_a`` from the part at ``T_b`` (both (4, 4) in the fitted view's
    optical frame, metres): :func:`~.observability.changed_pixels` of the part alone, rendered
    noise-free, with :class:`~.observability.ObservabilityParams`' depth noise and edges."""
    from tlessbot_ros.core.common.table_plane import table_frame_from_plane
    from tlessbot_ros.core.pose.observability import (
        ObservabilityParams,
        ViewOfTable,
        changed_pixels,
    )

    points = obj.model_points.astype(np.float64)
    settings = ObservabilityParams()
    total = 0
    for view in views:
        if view.plane is None:
            continue
        T_world_camera = table_frame_from_plane(view.plane)
        T_world_fit = T_world_camera @ view.T_view_fit
        total += changed_pixels(mesh, points, T_world_fit @ T_a, T_world_fit @ T_b,
                                ViewOfTable(view.intrinsics, T_world_camera), settings)[2]
    return total


def measures_smoothed(check: FlatCheck, obj: ObjectTemplates,
                       mesh: o3d.t.geometry.RaycastingScene, pose: np.ndarray,
                       views: Sequence[ViewEvidence]) -> bool:
    """Whether the depth at ``pose`` measures smoothed (:func:`~.flat_align.pose_spread_px`
    > 0): a stereo-like depth that fills a block's holes."""
    from tlessbot_ros.core.pose.flat_align import pose_spread_px

    return pose_spread_px(mesh, pose, obj.model_points.astype(np.float64), views,
                          align_at_1m_m=check.params.align_at_1m_m,
                          tolerance_m=check.params.depth_tolerance_m) > 0


def _wins_every_duel(votes: np.ndarray, k: int) -> bool:
    """Whether pose ``k`` has more pixels for it than against it in each of its duels
    (``votes`` (N, N) [i, j]: pixels for i against j)."""
    return all(int(votes[k, j]) > int(votes[j, k]) for j in range(len(votes)) if j != k)


def _edge_winner(check: FlatCheck, obj: ObjectTemplates, mesh: o3d.t.geometry.RaycastingScene,
                 poses: list[np.ndarray], views: Sequence[ViewEvidence], params: TurnParams,
                 smoothed: bool) -> tuple[int, bool] | None:
    """(the turn among ``poses`` (the fit first) that wins most duels on the image's edges
    inside the outline and beats the fit there by the aligned votes' margin
    (:func:`~.image_edges.edge_winner`), True), or None: ``box_image_edges`` off, or no turn
    does (with ``box_edges_smoothed_only``, only where ``smoothed``: :func:`measures_smoothed`
    at the fit). On a smoothed depth the holes' few millimetres leave the height votes open;
    their rims and the chamfers' creases stay edges of the image."""
    from tlessbot_ros.core.pose.image_edges import edge_winner

    if not params.box_image_edges:
        return None
    if params.box_edges_smoothed_only and not smoothed:
        # a per-pixel depth shows the holes' millimetres: where it leaves the round open, an
        # image edge is as likely the part's own shading (docs/bench/edge-votes-polarity.md)
        return None
    k = edge_winner(mesh, poses, obj.model_points.astype(np.float64), views,
                    min_z=check.params.align_min_z, align_at_1m_m=check.params.align_at_1m_m,
                    jump_m=params.jump_m, crease_deg=params.crease_deg, edge_px=params.edge_px,
                    # an image edge within edge_px of the outline is the outline's
                    inner_px=params.box_edge_px + int(np.ceil(params.edge_px)),
                    hole_contrast=check.params.edge_hole_contrast)
    return (k, True) if k > 0 else None


def hull_moved_m(obj: ObjectTemplates, turn: np.ndarray) -> float:
    """How far (m) the model-frame ``turn`` (4, 4) carries the part's convex hull (of its mesh,
    else of its surface samples) out of itself: the largest distance of a turned hull vertex
    outside the hull; 0 for a turn that maps the hull onto itself (a drilled block's box
    turns), the head's overhang for a screw turned end for end."""
    from scipy.spatial import ConvexHull, QhullError

    def build() -> tuple[np.ndarray, np.ndarray]:
        points = obj.mesh_vertices if obj.mesh_vertices is not None else obj.model_points
        try:
            hull = ConvexHull(np.asarray(points, np.float64))
        except (QhullError, ValueError):      # a flat or tiny set: no hull to leave
            return np.zeros((0, 3)), np.zeros((0, 4))
        return hull.points[hull.vertices], hull.equations

    vertices, planes = obj.derived('convex_hull', build)
    if not len(planes):
        return 0.0
    moved = vertices @ turn[:3, :3].T + turn[:3, 3]
    return max(0.0, float((moved @ planes[:, :3].T + planes[:, 3]).max()))


def _distinct_by_fitness(poses: list[np.ndarray], more: list[np.ndarray], fitness: np.ndarray,
                         fitted: float, params: TurnParams) -> list[np.ndarray]:
    """``poses`` and, best depth ``fitness`` first, those of ``more`` at most
    ``max_fitness_drop`` below the ``fitted`` pose's that differ from every pose taken (a turn
    refitted onto another would split the duels it is part of), until ``half_candidates``
    compete besides the fitted pose."""
    from tlessbot_ros.core.pose.candidates import poses_differ

    poses = list(poses)
    for k in np.argsort(-np.asarray(fitness), kind='stable'):
        if len(poses) > params.half_candidates or fitness[k] < fitted - params.max_fitness_drop:
            break
        if all(poses_differ(more[k], T) for T in poses):
            poses.append(more[k])
    return poses


__all__ = ['box_turns', 'choose_half_turn', 'half_turn_axes', 'hull_moved_m', 'measures_smoothed',
           'self_half_turns', 'turn_seen_px']
