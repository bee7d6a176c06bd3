"""Near-symmetric turns of a fitted part, told apart by the edges of the colour image.

A part whose surface nearly maps onto itself under a turn (a disc with four small holes turned
by any angle about its axis, a drilled block turned over) fits its depth almost as well in
either pose: the features that break the symmetry are a few millimetres wide, and a stereo
depth camera smooths them away (the holes of a 6 mm disc read as solid in simulated D435
depth). The colour image keeps them: a hole's rim, a chamfer's crease and the outline are
edges. :func:`near_turns` lists, once per part, the turns about its axes by multiples of
``step_deg`` that map most of its surface onto itself without being exact symmetries;
:func:`choose_turn` renders the fitted pose and each of its turns that the depth does not
reject, and keeps the pose whose rendered edges (outline, depth steps, creases) lie on more
image edges (Canny, PAMI 1986; a one-sided chamfer test as in Barrow et al., IJCAI 1977).

Poses are ``T_camera_object`` (4, 4) metres, optical frame; turns are (4, 4) transforms in
the model frame, about an axis through the surface centroid.
"""
from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, cast

import numpy as np

from tlessbot_ros.core.common import (
    CameraIntrinsics,
    o3d_tensor,
    rotation_about_axis,
    rotation_angle_deg,
)
from tlessbot_ros.core.pose.database import ObjectTemplates
from tlessbot_ros.core.pose.fallback import turn_axes

if TYPE_CHECKING:
    import open3d as o3d

    from tlessbot_ros.core.pose.flat import ViewEvidence


@dataclass(frozen=True)
class TurnParams:
    """Settings of the near-symmetric turn check (:func:`choose_turn`).

    Attributes:
        enabled: run the check on parts whose templates hold their mesh.
        step_deg: turns about each axis are tried at multiples of this (0 < step <= 90).
        min_turn_deg: turns by less are not tried (the fit's own refinement settles them).
        near_ratio: a turn is near-symmetric when the median distance of the turned surface
            samples to the nearest sample is at most this many sample spacings (>= 1).
        exact_ratio: ... and an exact symmetry (not tried: it looks the same) when the
            ``exact_quantile`` of those distances is at most this many spacings too.
        exact_quantile: that quantile (0..1): high, so that small features count.
        max_fitness_drop: a turn competes only when its depth fitness is at most this below
            the fitted pose's (0..1).
        min_gain: a turn replaces the fitted pose when this larger a share of its rendered
            edges lies on image edges (0..1).
        min_edge_px: ... and it renders at least this many edge pixels (>= 1).
        edge_px: a rendered edge pixel within this distance of a Canny edge is supported, px.
        jump_m: neighbouring rendered pixels whose depths differ by more are an edge, m.
        crease_deg: neighbouring rendered pixels whose normals differ by more are an edge.
        points: the ROI points the turns' depth fitness is measured on, at most (>= 10).
        half_turns: also try the half turns that map much of the part onto itself
            (:mod:`.half_turns`), decided by the aligned votes of every view.
        half_min_share: ... those that put at least this share of its surface samples within
            its voxel of the surface (0..1).
        half_icp_iterations: ICP steps refitting each turned pose to the ROI cloud (>= 1; the
            fit's polish takes 30).
        half_candidates: at most this many refitted turns, best by depth, compete (>= 1).
        box_refine_deg: the fit and its box turns are refined on every view's image before
            their vote, first by steps of this many degrees (0: compared as they are).
        box_refine_min_deg: ... halved down to this step, degrees (> 0).
        box_refine_max_deg: ... each staying within this turn of where it began, degrees.
        box_refine_max_m: ... and within this distance, m (>= 0); turns that carry the part's
            hull farther out of itself are compared as they are.
        box_edge_px: the refined poses vote on the pixels inside both outlines and this many
            pixels or more from either (>= 0).
        box_image_edges: a box round the height votes leave open is decided on the image's
            edges inside the outline (:mod:`.image_edges`), by the aligned votes' margin.
        box_edges_smoothed_only: ... only where the fit measures the depth smoothed
            (:func:`~.flat_align.pose_spread_px` > 0); on per-pixel depth an open round keeps it.
        box_agreed_turn: a round still open on per-pixel depth takes the turn that wins every
            duel both as the poses are and refined on the image (False: the fit stays).
        box_agreed_min_px: ... only where that turn changes at least this many pixels of the
            fit, all views (:func:`~.observability.changed_pixels`; >= 0).
    """

    enabled: bool = True
    step_deg: float = 5.0
    min_turn_deg: float = 15.0
    near_ratio: float = 1.6
    exact_ratio: float = 3.0
    exact_quantile: float = 0.98
    max_fitness_drop: float = 0.05
    min_gain: float = 0.04
    min_edge_px: int = 30
    edge_px: float = 1.5
    jump_m: float = 0.002
    crease_deg: float = 30.0
    points: int = 500
    half_turns: bool = True
    half_min_share: float = 0.4
    half_icp_iterations: int = 30
    half_candidates: int = 3
    box_refine_deg: float = 1.0
    box_refine_min_deg: float = 0.25
    box_refine_max_deg: float = 3.0
    box_refine_max_m: float = 0.001
    box_edge_px: int = 1
    box_image_edges: bool = True
    box_edges_smoothed_only: bool = True
    box_agreed_turn: bool = True
    box_agreed_min_px: int = 20

    def __post_init__(self) -> None:
        if not 0.0 < self.step_deg <= 90.0:
            raise ValueError(f'step_deg must be in (0, 90] degrees, got {self.step_deg}')
        if not 0.0 <= self.min_turn_deg < 180.0:
            raise ValueError(f'min_turn_deg must be in [0, 180), got {self.min_turn_deg}')
        if self.near_ratio < 1.0 or self.exact_ratio < 1.0:
            raise ValueError('near_ratio and exact_ratio are >= 1 (sample spacings), got '
                             f'{self.near_ratio}, {self.exact_ratio}')
        if not 0.0 < self.exact_quantile <= 1.0:
            raise ValueError(f'exact_quantile must be in (0, 1], got {self.exact_quantile}')
        if not 0.0 <= self.max_fitness_drop <= 1.0 or not 0.0 <= self.min_gain <= 1.0:
            raise ValueError('max_fitness_drop and min_gain are shares in 0..1, got '
                             f'{self.max_fitness_drop}, {self.min_gain}')
        if self.min_edge_px < 1 or self.points < 10 or self.edge_px <= 0 or self.jump_m <= 0:
            raise ValueError('min_edge_px must be >= 1, points >= 10, edge_px and jump_m > 0')
        if not 0.0 <= self.half_min_share <= 1.0 or self.half_icp_iterations < 1 or \
                self.half_candidates < 1:
            raise ValueError('half_min_share must be in 0..1, half_icp_iterations and '
                             'half_candidates >= 1, got '
                             f'{self.half_min_share}, {self.half_icp_iterations}, '
                             f'{self.half_candidates}')
        if self.box_refine_deg < 0 or self.box_refine_min_deg <= 0 or \
                self.box_refine_max_deg < 0 or self.box_refine_max_m < 0 or \
                self.box_edge_px < 0 or self.box_agreed_min_px < 0:
            raise ValueError('box_refine_deg, box_refine_max_deg, box_refine_max_m, '
                             'box_edge_px and box_agreed_min_px must be >= 0 and '
                             'box_refine_min_deg > 0, got '
                             f'{self.box_refine_deg}, {self.box_refine_max_deg}, '
                             f'{self.box_refine_max_m}, {self.box_edge_px}, '
                             f'{self.box_agreed_min_px}, {self.box_refine_min_deg}')


def surface_centre(obj: ObjectTemplates) -> np.ndarray:
    """The area-weighted centroid of the part's mesh surface (of its surface samples without a
    mesh): the samples' own mean is a few tenths of a millimetre off (3000 random samples),
    enough to make a turn about it miss an exact symmetry's small features."""
    if obj.mesh_vertices is None or obj.mesh_faces is None:
        return cast(np.ndarray, obj.model_points.astype(np.float64).mean(axis=0))
    triangles = np.asarray(obj.mesh_vertices, np.float64)[obj.mesh_faces]      # (F, 3, 3)
    area = 0.5 * np.linalg.norm(np.cross(triangles[:, 1] - triangles[:, 0],
                                         triangles[:, 2] - triangles[:, 0]), axis=1)
    return cast(np.ndarray, (area @ triangles.mean(axis=1)) / max(float(area.sum()), 1e-12))


def near_turns(obj: ObjectTemplates, *, step_deg: float = 5.0, min_turn_deg: float = 15.0,
               near_ratio: float = 1.6, exact_ratio: float = 3.0,
               exact_quantile: float = 0.98) -> np.ndarray:
    """(K, 4, 4) the part's near-symmetric turns that are not exact symmetries (cached).

    Candidates: turns by multiples of ``step_deg`` (``min_turn_deg`` or more) about the model
    frame's axes and the surface's principal axes, through the surface centroid
    (:func:`surface_centre`). Each is judged by the distances of the turned surface samples
    to the nearest sample, in units of the median spacing of neighbouring samples:
    near-symmetric when their median is at most ``near_ratio`` (most of the surface maps onto
    itself: a generic turn by 20° scores 1.8-3, a half-turn of a drilled block 1.2-1.5), exact
    when their ``exact_quantile`` is at most ``exact_ratio`` too (the small features map as
    well: 2.2-2.7 for the listed symmetries of the generated parts, 3.5-6 for the turns of a
    disc with four holes and the half-turns of a drilled block); where the templates hold the
    part's listed symmetries (``listed_rotations``), a turn is exact when it is one of those
    (within half a step) instead, and those are the exact ones. A part with a continuous axis
    has no turn about it here (all exact). Turns within ``min_turn_deg`` of an exact symmetry
    (the identity too) are left out: they are that symmetry and a small turn, which the fit's
    own refinement settles. About an axis the surface nearly turns on at every angle (every
    turn from ``min_turn_deg`` on near or exact, one near at least) the smaller turns are
    listed too: there the depth settles no turn at all.
    """
    key = ('near_turns', float(step_deg), float(min_turn_deg), float(near_ratio),
           float(exact_ratio), float(exact_quantile))

    def build() -> np.ndarray:
        model = obj.model_points.astype(np.float64)
        tree = obj.model_tree()
        sub = model[::max(1, len(model) // 1500)]
        spacing = float(np.median(tree.query(sub, k=2)[0][:, 1]))  # [:, 0]: the sample itself
        centre = surface_centre(obj)
        count = int(round(360.0 / step_deg))
        angles = 360.0 * np.arange(1, count) / count
        large = np.minimum(angles, 360.0 - angles) >= min_turn_deg - 1e-6
        # the part's listed symmetries, where the templates hold them, are its exact ones
        # (those the scorer uses): holes small against the sampling do not make a turn exact
        listed = obj.listed_rotations
        exact, turns, fine = [np.eye(3)] + list(listed if listed is not None else []), [], []
        for axis in turn_axes(model):
            kinds = []
            for angle in angles:
                S = np.eye(4)
                S[:3, :3] = rotation_about_axis(axis, np.radians(angle))
                S[:3, 3] = centre - S[:3, :3] @ centre
                d = tree.query(sub @ S[:3, :3].T + S[:3, 3])[0] / spacing
                exact_turn = np.quantile(d, exact_quantile) <= exact_ratio if listed is None \
                    else float(np.max(np.einsum('ij,kij->k', S[:3, :3], listed))) >= \
                    1.0 + 2.0 * np.cos(np.radians(step_deg / 2))   # trace: within half a step
                kinds.append((S, 'exact' if exact_turn
                              else 'near' if np.median(d) <= near_ratio else 'far'))
            big = [kind for (_, kind), is_large in zip(kinds, large) if is_large]
            exact += [S[:3, :3] for (S, kind), is_large in zip(kinds, large)
                      if is_large and kind == 'exact']
            turns += [S for (S, kind), is_large in zip(kinds, large)
                      if is_large and kind == 'near']
            if 'far' not in big and 'near' in big:
                # nearly continuous about this axis (a disc with small holes): its small
                # turns too, which the depth cannot settle either
                fine += [S for (S, _), is_large in zip(kinds, large) if not is_large]
        # a turn within min_turn_deg of an exact symmetry (the identity too) is that symmetry
        # and a small turn, which the fit's refinement settles (but about a nearly continuous
        # axis: those are the fine turns)
        far = [S for S in turns
               if min(rotation_angle_deg(S[:3, :3], R) for R in exact) >= min_turn_deg - 1e-6]
        return np.array(far + fine).reshape(-1, 4, 4)
    return cast(np.ndarray, obj.derived(key, build))


def rendered_edges(scene: o3d.t.geometry.RaycastingScene, T_camera_object: np.ndarray,
                   intrinsics: CameraIntrinsics, box: tuple[int, int, int, int], *,
                   jump_m: float, crease_deg: float) -> np.ndarray:
    """(h, w) bool edges of a mesh at a pose in the image window ``box`` (x, y, w, h): pixels
    next to a neighbour that the mesh covers and they do not (its outline, a through hole), or
    whose depth lies more than ``jump_m`` off the plane of the other's surface (a step, a
    hole's rim: a surface seen at a grazing angle is no edge), or whose surface normal turns
    by more than ``crease_deg`` (a crease, a chamfer)."""
    x0, y0, w, h = box
    K = intrinsics.K
    v, u = np.mgrid[y0:y0 + h, x0:x0 + w].astype(np.float64)
    rays_c = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)],
                      axis=-1)                                # (h, w, 3)
    T = np.asarray(T_camera_object, np.float64)
    rays = np.empty((h * w, 6), np.float32)
    rays[:, :3] = -T[:3, :3].T @ T[:3, 3]     # the camera centre in the model frame
    rays[:, 3:] = rays_c.reshape(-1, 3) @ T[:3, :3]   # z = 1 in the camera: the hit is depth
    cast_out = scene.cast_rays(o3d_tensor(rays))
    depth = cast_out['t_hit'].numpy().astype(np.float64).reshape(h, w)
    normals = (cast_out['primitive_normals'].numpy().astype(np.float64)
               @ T[:3, :3].T).reshape(h, w, 3)               # in the camera frame
    hit = np.isfinite(depth)
    depth = np.where(hit, depth, 0.0)
    offset = np.einsum('ijk,ijk->ij', normals, rays_c) * depth    # n . P, P = depth * ray
    cos_crease = np.cos(np.radians(crease_deg))
    edges = np.zeros((h, w), bool)
    for a, b in (((slice(None, -1), slice(None)), (slice(1, None), slice(None))),
                 ((slice(None), slice(None, -1)), (slice(None), slice(1, None)))):
        both = hit[a] & hit[b]
        off_plane = np.zeros(both.shape, bool)
        for p, q in ((a, b), (b, a)):   # q's depth against the plane of p's surface
            along = np.einsum('ijk,ijk->ij', normals[p], rays_c[q])
            with np.errstate(divide='ignore', invalid='ignore'):
                predicted = offset[p] / along
            off_plane |= ~(np.abs(depth[q] - predicted) <= jump_m)   # nan: off
        edge = (hit[a] != hit[b]) | (both & off_plane) | \
            (both & (np.einsum('ijk,ijk->ij', normals[a], normals[b]) < cos_crease))
        edges[a] |= edge
        edges[b] |= edge
    return edges


def edge_support(scene: o3d.t.geometry.RaycastingScene, poses: Sequence[np.ndarray],
                 views: Sequence[ViewEvidence], model_points: np.ndarray,
                 params: TurnParams) -> tuple[np.ndarray, np.ndarray]:
    """For K poses of the fitted view (``T_camera_object``): (K,) rendered edge pixels over
    every view and (K,) of them within ``edge_px`` of a Canny edge of the image
    (:func:`~tlessbot_ros.core.pose.silhouette.edge_distance`)."""
    from tlessbot_ros.core.pose.silhouette import edge_distance, window

    total = np.zeros(len(poses))
    supported = np.zeros(len(poses))
    for view in views:
        in_view = [view.T_view_fit @ T for T in poses]
        box = window(model_points, in_view, view.intrinsics, margin_px=4)
        if box is None or view.rgb is None:
            continue
        distance = edge_distance(view.rgb, box)
        for k, T in enumerate(in_view):
            edges = rendered_edges(scene, T, view.intrinsics, box, jump_m=params.jump_m,
                                   crease_deg=params.crease_deg)
            total[k] += np.count_nonzero(edges)
            supported[k] += np.count_nonzero(distance[edges] <= params.edge_px)
    return total, supported


def choose_turn(obj: ObjectTemplates, scene: o3d.t.geometry.RaycastingScene,
                T_camera_object: np.ndarray, views: Sequence[ViewEvidence],
                fitness: Callable[[np.ndarray], np.ndarray], params: TurnParams
                ) -> tuple[np.ndarray, dict[str, float]]:
    """The fitted pose or a near-symmetric turn of it (:func:`near_turns`) whose rendered
    edges the colour images support best.

    A turn replaces the pose when its share of rendered edge pixels on image edges exceeds
    the pose's by ``min_gain``, scaled by its angle over ``min_turn_deg`` when smaller (a
    small turn moves the edges by a pixel or two, so fewer of them can newly land on image
    edges), and it renders at least ``min_edge_px`` edge pixels. The small turns (under
    ``min_turn_deg``, where the part has any) and the larger ones by an even number of steps
    are tried first; a turned pose is then checked against the small turns again (they reach
    the steps skipped).

    Args:
        obj: the part's templates.
        scene: its mesh, an Open3D ``RaycastingScene`` in the model frame.
        T_camera_object: (4, 4) the fitted pose in the fitted view.
        views: the colour views (:class:`~tlessbot_ros.core.pose.ViewEvidence`: each one's
            image, intrinsics and ``T_view_fit``; the label mask is not used).
        fitness: (K, 4, 4) poses -> (K,) depth fitness on the part's ROI (0..1).
        params: the settings.

    Returns:
        the pose and what decided: ``turns`` tried, ``support`` of the fitted pose and
        ``best_support`` of the chosen pose (shares of rendered edge pixels on image edges),
        ``turned_deg`` (the angle between the fitted and the chosen pose; 0 when it stays).
    """
    T0 = np.asarray(T_camera_object, np.float64)
    info = {'turns': 0.0, 'support': 0.0, 'best_support': 0.0, 'turned_deg': 0.0}
    turns = near_turns(obj, step_deg=params.step_deg, min_turn_deg=params.min_turn_deg,
                       near_ratio=params.near_ratio, exact_ratio=params.exact_ratio,
                       exact_quantile=params.exact_quantile)
    if not len(turns) or not views:
        return T0, info
    angles = np.array([rotation_angle_deg(S[:3, :3], np.eye(3)) for S in turns])
    steps = np.round(angles / params.step_deg).astype(int)
    coarse = (steps % 2 == 0) & (angles >= params.min_turn_deg)
    required = params.min_gain * np.minimum(1.0, angles / max(params.min_turn_deg, 1e-9))
    T = T0
    for round_ in range(2):
        # the first round on the small turns and every other step of the larger ones (and
        # the half-turns), the second, after a turn, on the small turns alone
        small = angles < params.min_turn_deg
        tried = np.flatnonzero(small if round_ else small | coarse | (angles >= 180.0 - 1e-6))
        if not len(tried):
            break
        poses = np.concatenate([T[None], T @ turns[tried]])
        fit = fitness(poses)
        keep = np.flatnonzero(fit >= fit[0] - params.max_fitness_drop)   # 0 is always kept
        info['turns'] += float(len(keep) - 1)
        if len(keep) < 2:
            break
        total, supported = edge_support(scene, [poses[k] for k in keep], views,
                                        obj.model_points.astype(np.float64), params)
        share = np.where(total > 0, supported / np.maximum(total, 1), 0.0)
        margin = share[1:] - share[0] - required[tried[keep[1:] - 1]]
        margin[total[1:] < params.min_edge_px] = -np.inf
        best = int(np.argmax(margin))
        if round_ == 0:
            info['support'] = info['best_support'] = float(share[0])
        if margin[best] <= 0:
            break
        T = poses[keep[best + 1]]
        info['best_support'] = float(share[best + 1])
    info['turned_deg'] = rotation_angle_deg(T[:3, :3], T0[:3, :3])
    return T, info
