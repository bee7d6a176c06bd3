"""Flat parts: which face is up, told by the depth and by what the depth cannot see.

A part a few millimetres thick shows the depth camera one flat face. Turned upside down
(a half turn about an axis in the table plane) it shows the same flat face at the same height,
and its outline becomes the mirror image of the true one: the depth fit explains the ROI cloud
about as well either way (ADD-S is blind to the turn too; docs/bench/flat-parts.md).
The outline itself is not blind to it: an
asymmetric plate, a bracket or a spanner turned over shows its corner cut, its holes and its
jaw on the other side.

:class:`FlatCheck` is the one orientation check of a flat part (resting height at most
``flat_ratio`` of its diameter), run after its depth fit. Where the views have a table frame
and the part its mesh, :meth:`FlatCheck.aligned_turn` compares the fitted pose with its exact
half turns about the axes of its outline (and, for a round outline, its turns about the thin
axis; :mod:`~tlessbot_ros.core.pose.flat_turns`), the part's look-alike twins at each of them:
every candidate is ray-cast into every view as heights above the table, aligned to the view by
a few pixels, and every two are compared pixel by pixel on the measured height and the colour
(:mod:`~tlessbot_ros.core.pose.flat_align`); the winner of their duels replaces the fitted
pose (and names the part) when it beats every other by a clear margin. Otherwise (no table
frame, no mesh) the former image round: the fitted pose turned over about ``flips`` horizontal
axes, and end for end, refitted by a short ICP each; the turned fits within
``fitness_margin`` compete on the colour of the pixels their silhouettes dispute
(:mod:`~tlessbot_ros.core.pose.silhouette`; ``min_share`` of at least ``min_disputed_px``),
with fewer such pixels on their agreement with the Canny edges (Canny, PAMI 1986; a one-sided
chamfer match as in Barrow et al., IJCAI 1977) and the label (``min_gain``). The winner gets
the fitted pose's polish, and :func:`~.flat_turns.refine_yaw` checks the yaw on the image.

Unless the aligned votes decided, the depth has the last word (:meth:`FlatCheck.depth_turn`):
the final pose turned by half a turn about each principal axis of the mesh, each refitted to
the ROI cloud, is ray-cast along the part's depth pixels in every view, and a turn that
explains more of them than the pose refitted alike (``depth_refit_both``) by a clear margin
(:func:`~.lookalike.pooled_vote`, within ``depth_tolerance_m``, ``depth_min_z``; a pixel the
mesh misses, where a hole is, expects the table behind it) replaces it.

Poses are ``T_camera_object`` (4, 4) float64, metres, optical frame.
"""
from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from tlessbot_ros.core.common import invert_transform, rotation_about_axis, transform_points
from tlessbot_ros.core.pose.candidates import poses_differ
from tlessbot_ros.core.pose.flat_params import MESH_FLAT_RATIO as MESH_FLAT_RATIO
from tlessbot_ros.core.pose.flat_params import FlatParams as FlatParams
from tlessbot_ros.core.pose.flat_params import ViewEvidence as ViewEvidence
from tlessbot_ros.core.pose.flat_params import is_flat as is_flat
from tlessbot_ros.core.pose.flat_params import is_flat_mesh as is_flat_mesh
from tlessbot_ros.core.pose.flat_turns import (
    bbox_centre,
    mesh_scene,
    outline_half_turns,
    outline_yaws,
    principal_half_turns,
    refit_to_surface,
)
from tlessbot_ros.core.pose.silhouette import (
    agreement,
    disputed_votes,
    edge_distance,
    silhouette,
    window,
)

if TYPE_CHECKING:
    import open3d as o3d

    from tlessbot_ros.core.pose.database import ObjectTemplates
    from tlessbot_ros.core.pose.refinement import Refiner


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


class FlatCheck:
    """Turns a flat part's fitted pose over when the image says the other face is up.

    Args:
        refiner: the pose stage's :class:`~tlessbot_ros.core.pose.Refiner` (ICP and fitness).
        params: :class:`FlatParams`.
        voxel_scale: the ROI's voxel edge in object voxels (``PoseParams.table_voxel_scale``).
    """

    def __init__(self, refiner: Refiner, params: FlatParams = FlatParams(), *,
                 voxel_scale: float = 1.0, sor_neighbors: int = 20,
                 sor_std_ratio: float = 2.0) -> None:
        self.refiner, self.params = refiner, params
        self.voxel_scale, self._sor = voxel_scale, (sor_neighbors, sor_std_ratio)
        # the last aligned round: its poses of the part itself and their duels' votes
        self.ranked: tuple[list[np.ndarray], np.ndarray] | None = None

    def applies(self, obj: ObjectTemplates) -> bool:
        """Whether ``obj`` is checked at all (enabled, and a flat part)."""
        return self.params.enabled and is_flat(obj, self.params.flat_ratio)

    def flipped_fits(self, obj: ObjectTemplates, T_camera_object: np.ndarray,
                     points_c: np.ndarray, T_world_camera: np.ndarray
                     ) -> tuple[float, list[tuple[np.ndarray, float]], np.ndarray]:
        """The fitted pose's depth fitness, the flipped fits that compete with it
        (``(T_camera_object, fitness)`` best first, at most ``candidates`` of them) and the
        prepared ROI cloud they were fitted to."""
        p = self.params
        scene = self.prepared_cloud(obj, points_c)
        centre = bbox_centre(obj)
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
            if all(poses_differ(refined[k], T) for T, _ in chosen):
                chosen.append((refined[k], float(flipped[k])))
        return own, chosen, scene

    def prepared_cloud(self, obj: ObjectTemplates, points_c: np.ndarray) -> np.ndarray:
        """The ROI cloud as the fit saw it: voxel-downsampled at the part's voxel (times
        ``voxel_scale``), statistical outliers removed."""
        from tlessbot_ros.core.pose.cloud import remove_statistical_outliers, voxel_downsample

        scene, _ = voxel_downsample(np.asarray(points_c, np.float64),
                                    obj.voxel_size_m * self.voxel_scale)
        if len(scene) >= 10:
            scene = scene[remove_statistical_outliers(scene, neighbors=self._sor[0],
                                                      std_ratio=self._sor[1])]
        return scene

    def image_evidence(self, obj: ObjectTemplates, poses: Sequence[np.ndarray],
                       views: Sequence[ViewEvidence]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """For K poses (the fitted one first): (K,) mean :func:`agreement` over the views,
        (K,) share of the pixels disputed between pose k and pose 0 that vote for pose k
        (:func:`disputed_votes`, summed over the views; 0.5 for pose 0 and without any) and
        (K,) the count of those pixels. Each view is read in the window around all the
        poses' silhouettes."""
        p = self.params
        points = obj.model_points.astype(np.float64)
        spacing = obj.sample_spacing_m()
        scores = np.zeros(len(poses))
        votes = np.zeros((len(poses), 2))
        used = 0
        for view in views:
            T = [view.T_view_fit @ np.asarray(T_k, np.float64) for T_k in poses]
            box = window(points, T, view.intrinsics, margin_px=8)
            if box is None or view.rgb is None:
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
                T_world_camera: np.ndarray, views: Sequence[ViewEvidence],
                twins: Sequence[ObjectTemplates] = ()
                ) -> tuple[np.ndarray | None, dict[str, float]]:
        """The turned pose that replaces the fitted one on the image (None: keep it) and what
        decided: ``{'fitness', 'flip_fitness', 'agreement', 'flip_agreement', 'flip_share',
        'disputed_px'}`` (only the fitness when no turned fit competes or no view has colour).

        With at least ``min_disputed_px`` pixels disputed between two silhouettes, a turned
        pose wins when more than ``min_share`` of them vote for it (and its agreement is not
        lower by more than ``min_gain``); with fewer, when its agreement is higher by more
        than ``min_gain``.

        With a mesh and views with a table frame, the aligned votes decide instead
        (:meth:`aligned_turn`), among the part and its look-alike ``twins`` at once."""
        p = self.params
        T0 = np.asarray(T_camera_object, np.float64)
        mesh = mesh_scene(obj)
        if mesh is not None and any(v.plane is not None for v in views):
            return self.aligned_turn(obj, mesh, T0, points_c, views, twins)
        own, flipped, scene = self.flipped_fits(obj, T0, points_c,
                                                np.asarray(T_world_camera, np.float64))
        info = {'fitness': own}
        if not flipped or not views:
            return None, info
        poses = [T0] + [T for T, _ in flipped]
        k = self.image_winner(obj, poses, views, info)
        if k == 0:
            return None, info
        info['flip_fitness'] = flipped[k - 1][1]
        # the winner gets the polish the fitted pose had (every ROI point, more steps)
        pose = self.refiner.params
        T = self.refiner.icp_batch(scene, obj, poses[k][None],
                                   iterations=max(pose.polish_iterations, p.icp_iterations),
                                   points=len(scene),
                                   distance_m=pose.polish_distance_voxels * obj.voxel_size_m)
        return T[0], info

    def aligned_turn(self, obj: ObjectTemplates, mesh: o3d.t.geometry.RaycastingScene,
                     T_camera_object: np.ndarray, points_c: np.ndarray,
                     views: Sequence[ViewEvidence], twins: Sequence[ObjectTemplates] = ()
                     ) -> tuple[np.ndarray | None, dict[str, float]]:
        """The fitted pose turned by half a turn about one of the axes of the part's outline
        (:func:`outline_half_turns`) when the aligned votes choose that turn
        (:meth:`aligned_winner`), polished on the ROI cloud; None to keep the fitted pose.
        The part's look-alike ``twins`` (they share its model frame) compete at each of these
        poses too: ``info['twin']`` is the id of the part that won (its own when undecided).

        The turns are exact, not refitted: a fit a few millimetres or degrees off in the
        table plane passes its error on to every turn alike (the turn is about the part's own
        centre), so where the outline looks the same turned, the poses differ only where the
        holes, slots and cut corners do."""
        from tlessbot_ros.core.pose.cloud import voxel_downsample
        from tlessbot_ros.core.pose.database import CONTINUOUS_YAW_PERIOD
        from tlessbot_ros.core.pose.image_edges import edge_winner, flat_edge_settings

        samples = obj.model_points.astype(np.float64)
        turns = obj.derived('outline_turns', lambda: outline_half_turns(samples) + outline_yaws(
            samples, obj.exact_yaw_period(),
            self.params.yaw_turns))
        base = [T_camera_object] + [T_camera_object @ turn for turn in turns]
        parts = [(obj, mesh)] + [(t, m) for t in twins if (m := mesh_scene(t)) is not None]
        info: dict[str, float] = {}
        rivals = None
        if len(obj.yaw_periods) and obj.yaw_periods[0] == CONTINUOUS_YAW_PERIOD and \
                obj.exact_yaw_period() != CONTINUOUS_YAW_PERIOD:
            # the depth holds no yaw of this part (a disc with small holes): the fitted yaw
            # is a guess, so the best turn need only beat it (and the twins), not each other
            # turn, of which the two beside the true yaw split the votes
            rivals = [0] + list(range(len(base), len(base) * len(parts)))
        faces = len(base) == 4 and rivals is None   # half turns only (docs/flat-parts.md)
        k = self.aligned_winner(obj, [m for _, m in parts for _ in base],
                                [T for _ in parts for T in base], views, info, rivals,
                                fitted=range(0, len(base) * len(parts), len(base))
                                if faces else ())
        winner, k = parts[k // len(base)][0], k % len(base)
        if not info['align_decided']:
            winner = obj   # a face taken undecided: the twins' own checks name the part
            if k == 0 and faces and self.params.edge_vote_px > 0:   # rims, slots (smoothed)
                k = edge_winner(mesh, base, samples, views, min_z=self.params.align_min_z,
                                **flat_edge_settings(self.params))
        info['twin'] = float(winner.obj_id)
        if k == 0:
            return None, info
        scene, _ = voxel_downsample(np.asarray(points_c, np.float64),
                                    winner.voxel_size_m * self.voxel_scale)
        pose = self.refiner.params
        T = self.refiner.icp_batch(scene, winner, base[k][None],
                                   iterations=max(pose.polish_iterations,
                                                  self.params.icp_iterations),
                                   points=len(scene),
                                   distance_m=pose.polish_distance_voxels * winner.voxel_size_m)
        info['flip_fitness'] = float(self.refiner.grid_fitness(T, scene, winner)[0])
        return T[0], info

    def aligned_winner(self, obj: ObjectTemplates,
                       meshes: Sequence[o3d.t.geometry.RaycastingScene],
                       poses: Sequence[np.ndarray], views: Sequence[ViewEvidence],
                       info: dict[str, float], rivals: Sequence[int] | None = None, *,
                       fitted: Sequence[int] = ()) -> int:
        """The pose among ``poses`` (of ``meshes``, the fitted pose of ``obj`` first) that the
        aligned height and colour votes of every view choose
        (:func:`~.flat_align.view_votes`): the winner of the duels between all of them
        (:func:`~.flat_align.round_robin`) when its surplus over every other pose (over the
        ``rivals`` among them, when given) is clear (``align_min_z``;
        ``info['align_decided']`` 1, the fitted pose kept as clearly as a turn is taken);
        else 0 (undecided), unless another pose clearly beats each of the ``fitted`` ones (the
        fitted pose, of each mesh): then the winner of the duels among the poses that no pose
        beats clearly (:func:`~.flat_align.undominated`; ``info['align_cleared']`` 1): a pose
        that another beats clearly is what the views rule out (docs/flat-parts.md)."""
        from tlessbot_ros.core.pose.flat_align import round_robin, undominated, view_votes
        from tlessbot_ros.core.pose.lookalike import clear_margin

        p = self.params
        votes = view_votes(meshes, poses, obj.model_points.astype(np.float64),
                           views, align_at_1m_m=p.align_at_1m_m, tolerance_m=p.depth_tolerance_m)
        k = round_robin(votes)
        decided = all(clear_margin(int(votes[k, j]), int(votes[j, k]), p.align_min_z)
                      for j in (range(len(poses)) if rivals is None else rivals) if j != k)
        info.update(align_winner=float(k), align_decided=float(decided), align_cleared=0.0)
        own = [j for j in range(len(poses)) if meshes[j] is meshes[0]]
        self.ranked = ([poses[j] for j in own], votes[np.ix_(own, own)])
        if decided:
            return k
        alive = undominated(votes, p.align_min_z)
        if not fitted or not alive or set(fitted) & set(alive):
            return 0
        info['align_cleared'] = 1.0
        return alive[round_robin(votes[np.ix_(alive, alive)])]

    def image_winner(self, obj: ObjectTemplates, poses: Sequence[np.ndarray],
                     views: Sequence[ViewEvidence], info: dict[str, float]) -> int:
        """The pose among ``poses`` (the fitted one first) that the colour image chooses
        without depth or a mesh (:meth:`image_evidence`), 0 for the fitted one."""
        p = self.params
        scores, share, disputed = self.image_evidence(obj, poses, views)
        decided = disputed >= p.min_disputed_px
        gain = np.where(decided, share - p.min_share, scores - scores[0] - p.min_gain)
        k = 1 + int(np.argmax(gain[1:]))
        info.update(agreement=float(scores[0]), flip_agreement=float(scores[k]),
                    flip_share=float(share[k]), disputed_px=float(disputed[k]))
        if gain[k] <= 0 or (decided[k] and scores[k] < scores[0] - p.min_gain):
            return 0
        return k

    def ranked_lower(self, T_from: np.ndarray, T_to: np.ndarray) -> bool:
        """Whether the last aligned round ranked the pose ``T_to`` below ``T_from`` by a clear
        margin (``depth_min_z``): each taken as the round's candidate nearest in rotation."""
        from tlessbot_ros.core.common import rotation_angle_deg
        from tlessbot_ros.core.pose.lookalike import clear_margin

        if self.ranked is None:
            return False
        poses, votes = self.ranked
        a, b = (int(np.argmin([rotation_angle_deg(T[:3, :3], P[:3, :3]) for P in poses]))
                for T in (T_from, T_to))
        return a != b and clear_margin(int(votes[a, b]), int(votes[b, a]),
                                       self.params.depth_min_z)

    def depth_turn(self, obj: ObjectTemplates, T_camera_object: np.ndarray,
                   points_c: np.ndarray,
                   more_views: Sequence[tuple[np.ndarray, np.ndarray]] = (),
                   T_world_camera: np.ndarray | None = None
                   ) -> tuple[np.ndarray | None, float]:
        """The last word of the depth on the final pose (after the image and the yaw): the pose
        turned by half a turn about each principal axis of the mesh (through the centre of its
        principal box), each refitted to the ROI cloud point-to-plane
        (:func:`~.flat_turns.refit_to_surface`), replaces it when it explains the depth of
        every view better by a clear margin (with the table frame ``T_world_camera``, a pixel
        the mesh misses expects the table, :func:`~.lookalike.depth_errors`) than the pose
        refitted alike (``depth_refit_both``; else the pose as it is). Returns (the turned
        pose or None, its vote)."""
        from tlessbot_ros.core.pose.lookalike import depth_errors, pooled_vote, view_planes

        mesh = mesh_scene(obj)
        if mesh is None or obj.mesh_vertices is None:
            return None, 0.0
        vertices = obj.mesh_vertices
        turns = obj.derived('half_turns', lambda: principal_half_turns(vertices))
        T0 = np.asarray(T_camera_object, np.float64)
        clouds = [(np.eye(4), np.asarray(points_c, np.float64))] + \
            [(np.asarray(T, np.float64), points) for points, T in more_views]
        planes = view_planes(T_world_camera, [T for T, _ in clouds[1:]])
        clouds3 = [(T, points, plane) for (T, points), plane in zip(clouds, planes)
                   if len(points)]
        if not clouds3:
            return None, 0.0
        # the incumbent gets the refit each turn gets: a turn wins on the face it shows, not
        # on the refit's slide onto the depth (smoothed depth, a pose the image moved)
        incumbent = refit_to_surface(obj, T0, points_c) if self.params.depth_refit_both else T0
        own = [depth_errors(mesh, T @ incumbent, points, plane) for T, points, plane in clouds3]
        best: np.ndarray | None = None
        best_vote = 0.0
        for turn in turns:
            turned = refit_to_surface(obj, T0 @ turn, points_c)
            vote = pooled_vote([depth_errors(mesh, T @ turned, points, plane)
                                for T, points, plane in clouds3],
                               own, self.params.depth_tolerance_m, self.params.depth_min_z)
            if vote > best_vote:
                best, best_vote = turned, vote
        return best, best_vote
