"""Look-alike parts: pairs whose surfaces nearly coincide, and whether a view shows the difference.

T-LESS has pairs of parts that share one model frame and almost all of their surface (obj_21/22 and
obj_25/26: nearly all of each surface within 2 mm of the other's; they differ in small features a
few millimetres high; docs/bench/code-figures.md). Lying on the table with those features down, or
turned away from a camera, the two parts look the same in that view: no single-view classifier can
tell them apart there, whatever its features. :func:`visible_difference` measures, for a view whose
ground-truth pose is known, the share of the part's visible pixels where the look-alike would
show another depth; the recognition benchmark uses it to report accuracy on the crops that do
show the difference (the analogue, for classes, of BOP's visible-surface discrepancy).

:func:`depth_vote` and :class:`LookalikeCheck` tell the two apart at run time, from a part's
fitted pose and its ROI cloud: both meshes are ray-cast along the cloud's pixel rays and the
pixels where one explains the measured depth better by more than a tolerance vote. The pose of
either part fits the other (they share their frame and most of their surface), so one fit
serves both.
"""
from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping, Sequence
from typing import cast

import numpy as np
import open3d as o3d

from tlessbot_ros.core.common import (
    CameraIntrinsics,
    o3d_tensor,
    raycasting_scene,
    sample_surface,
)

Mesh = tuple[np.ndarray, np.ndarray]  # (V, 3) vertices in metres, (F, 3) int faces
# A pixel the mesh does not cover counts as this far from the measured depth (m): as far as a
# gross error, so that a missing feature weighs like a wrong one.
MISS_ERROR_M = 0.01


def shared_surface(mesh_a: Mesh, mesh_b: Mesh, *, tolerance_m: float = 0.002,
                   samples: int = 20000, seed: int = 0) -> float:
    """Share of each surface within ``tolerance_m`` of the other's, the smaller of the two.

    Both meshes are taken in their own model frames (look-alike T-LESS parts share one), so
    this is 1.0 for identical parts and falls with every feature one has and the other lacks.
    Exact point-to-triangle distances of ``samples`` area-uniform points per surface.
    """
    shares = []
    for source, target in ((mesh_a, mesh_b), (mesh_b, mesh_a)):
        points = sample_surface(*source, samples, seed=seed, scheme='sqrt')[0].astype(np.float32)
        distance = raycasting_scene(*target).compute_distance(o3d_tensor(points)).numpy()
        shares.append(float(np.mean(distance <= tolerance_m)))
    return min(shares)


def lookalike_pairs(meshes: Mapping[int, Mesh], *, tolerance_m: float = 0.002,
                    min_shared: float = 0.8, extent_tolerance_m: float = 0.01
                    ) -> dict[int, tuple[int, ...]]:
    """{obj_id: look-alike ids} for parts that share at least ``min_shared`` of their surface
    (:func:`shared_surface`). Only parts whose bounding-box extents agree within
    ``extent_tolerance_m`` are compared: a feature that one part has and the other lacks
    may stick out that far (1 cm; the T-LESS look-alikes differ by 1 mm in extent).

    On the 23 T-LESS CAD models: obj_21/22 share 0.93, obj_25/26 0.93; the next pair, obj_19/20,
    0.61.
    """
    ids = sorted(meshes)
    extents = {i: np.ptp(np.asarray(meshes[i][0], np.float64), axis=0) for i in ids}
    pairs: dict[int, list[int]] = {}
    for k, a in enumerate(ids):
        for b in ids[k + 1:]:
            if np.max(np.abs(extents[a] - extents[b])) > extent_tolerance_m:
                continue
            if shared_surface(meshes[a], meshes[b], tolerance_m=tolerance_m) >= min_shared:
                pairs.setdefault(a, []).append(b)
                pairs.setdefault(b, []).append(a)
    return {i: tuple(others) for i, others in pairs.items()}


def depth_along(scene: o3d.t.geometry.RaycastingScene, T_camera_object: np.ndarray,
                 rays_c: np.ndarray) -> np.ndarray:
    """Depth (m, inf where no hit) of a mesh at ``T_camera_object`` along (N, 3) camera rays
    scaled to z = 1."""
    T = np.asarray(T_camera_object, np.float64)
    R, t = T[:3, :3], T[:3, 3]
    rays = np.empty((len(rays_c), 6), np.float32)
    rays[:, :3] = -R.T @ t          # the camera centre in the model frame
    rays[:, 3:] = rays_c @ R        # z = 1 in the camera: the hit distance is the depth
    return cast(np.ndarray, scene.cast_rays(o3d_tensor(rays))['t_hit'].numpy())


def visible_difference(scene_a: o3d.t.geometry.RaycastingScene,
                       scene_b: o3d.t.geometry.RaycastingScene, T_camera_object: np.ndarray,
                       intrinsics: CameraIntrinsics, mask: np.ndarray, *,
                       tolerance_m: float = 0.002) -> float:
    """Share of the ``mask`` pixels where parts a and b, both at ``T_camera_object``, would
    show depths more than ``tolerance_m`` apart (or only one of them a surface).

    Args:
        scene_a, scene_b: the two parts' meshes in their (shared) model frame, metres, as
            :func:`~tlessbot_ros.core.common.raycasting_scene` (built once per part).
        T_camera_object: (4, 4) pose in the camera's optical frame.
        intrinsics: the camera's pinhole intrinsics.
        mask: (H, W) bool visible pixels of the part in this view.

    Returns:
        a fraction in [0, 1] (0 for an empty mask): 0 means this view cannot tell a from b.
    """
    rows, cols = np.nonzero(mask)
    if len(rows) == 0:
        return 0.0
    rays_c = np.stack([(cols - intrinsics.cx) / intrinsics.fx,
                       (rows - intrinsics.cy) / intrinsics.fy, np.ones(len(rows))], axis=1)
    depth_a, depth_b = (depth_along(scene, T_camera_object, rays_c)
                        for scene in (scene_a, scene_b))
    hit_a, hit_b = np.isfinite(depth_a), np.isfinite(depth_b)
    differs = hit_a != hit_b
    both = hit_a & hit_b
    differs[both] = np.abs(depth_a[both] - depth_b[both]) > tolerance_m
    return float(np.mean(differs))


def depth_errors(scene: o3d.t.geometry.RaycastingScene, T_camera_object: np.ndarray,
                 points_c: np.ndarray, plane: np.ndarray | None = None) -> np.ndarray:
    """(N,) |rendered - measured| depth (m) of a mesh at a pose along the pixel rays of an ROI
    cloud ((N, 3) points, optical frame), at most ``MISS_ERROR_M``.

    Where the ray misses the mesh (a through-hole, beside the outline) it meets what lies
    behind the part: with the table ``plane`` (4,) (n·x + d = 0, camera frame;
    :func:`~tlessbot_ros.core.common.plane_of_frame`) the rendered depth there is the table's,
    else the pixel counts as ``MISS_ERROR_M``. Without the table a hole that the depth shows
    (the table 4 mm below a plate's top) is explained better by a twin without that hole (4 mm
    off) than by the part that has it (a miss), which turns every such vote the wrong way."""
    points_c = np.asarray(points_c, np.float64)
    z = points_c[:, 2]
    rays = points_c / z[:, None]
    depth = depth_along(scene, T_camera_object, rays)
    if plane is not None:
        depth = np.where(np.isfinite(depth), depth, table_depth(plane, rays))
    return np.where(np.isfinite(depth), np.minimum(np.abs(depth - z), MISS_ERROR_M),
                    MISS_ERROR_M)


def table_depth(plane: np.ndarray, rays_c: np.ndarray) -> np.ndarray:
    """(N,) depth (m) at which (N, 3) camera rays scaled to z = 1 meet the ``plane`` (4,)
    (n·x + d = 0, camera frame); inf where a ray runs parallel to it or meets it behind the
    camera."""
    plane = np.asarray(plane, np.float64)
    along = rays_c @ plane[:3]
    with np.errstate(divide='ignore', invalid='ignore'):
        depth = -plane[3] / along
    return np.where(np.isfinite(depth) & (depth > 0), depth, np.inf)


def depth_vote(errors_a: np.ndarray, errors_b: np.ndarray, tolerance_m: float) -> float:
    """Share of the pixels that a explains better than b by more than ``tolerance_m``, minus
    the share that b explains better: > 0 favours a. Counting pixels rather than summing errors
    keeps the sensor noise (about 2 mm at 1 m on a D415) from deciding."""
    favour, against = vote_counts(errors_a, errors_b, tolerance_m)
    return (favour - against) / len(errors_a) if len(errors_a) else 0.0


def vote_counts(errors_a: np.ndarray, errors_b: np.ndarray, tolerance_m: float
                ) -> tuple[int, int]:
    """(pixels that a explains better than b by more than ``tolerance_m``, pixels that b
    explains better): the two halves of :func:`depth_vote`, as counts, so that the pixels of
    several views can be pooled."""
    gain = np.asarray(errors_b) - np.asarray(errors_a)
    return int(np.count_nonzero(gain > tolerance_m)), int(np.count_nonzero(gain < -tolerance_m))


def clear_margin(favour: int, against: int, min_z: float) -> bool:
    """Whether ``favour`` pixels against ``against`` are more than chance: the surplus
    ``favour - against`` exceeds ``min_z`` standard deviations of a fair coin tossed
    ``favour + against`` times (a sign test; ``min_z`` = 0: any surplus).

    Where the features that tell two look-alikes apart face away from the camera, the few
    pixels that still vote lie on edges and in the depth noise, and they split about evenly
    (e.g. 1 against 3, 4 against 7); where a view shows the features, dozens to hundreds of
    pixels vote, mostly one way. Pixels next to each other are not independent, so the test
    is a floor, not a probability."""
    surplus = favour - against
    return surplus > 0 and surplus > min_z * np.sqrt(favour + against)


def pooled_vote(challenger: Sequence[np.ndarray], incumbent: Sequence[np.ndarray],
                tolerance_m: float, min_z: float) -> float:
    """The challenger's vote against the incumbent over the pixels of several views (per view
    the (N,) depth errors of each, :func:`depth_errors`): the share of all pixels it explains
    better minus the share it explains worse, or 0 without a clear margin
    (:func:`clear_margin`)."""
    favour = against = 0
    for errors_a, errors_b in zip(challenger, incumbent):
        f, a = vote_counts(errors_a, errors_b, tolerance_m)
        favour, against = favour + f, against + a
    total = sum(len(errors) for errors in incumbent)
    if not total or not clear_margin(favour, against, min_z):
        return 0.0
    return (favour - against) / total


def view_planes(T_world_camera: np.ndarray | None, T_others_camera: Sequence[np.ndarray]
                ) -> list[np.ndarray | None]:
    """The table plane (4,) in a camera (its table frame ``T_world_camera``) and in each other
    camera (``T_other_camera``: that camera into the other one), all None without a table
    frame (:func:`~tlessbot_ros.core.common.plane_of_frame`)."""
    from tlessbot_ros.core.common import plane_of_frame

    if T_world_camera is None:
        return [None] * (1 + len(T_others_camera))
    T_world = np.asarray(T_world_camera, np.float64)
    planes: list[np.ndarray | None] = [plane_of_frame(T_world)]
    return planes + [plane_of_frame(T_world @ np.linalg.inv(T)) for T in T_others_camera]


class MeshScenes:
    """Ray-casting scenes of meshes by id, built on first use (or all at :meth:`warm_up`)."""

    def __init__(self, meshes: Mapping[int, Mesh]) -> None:
        self.meshes = dict(meshes)
        self._scenes: dict[int, o3d.t.geometry.RaycastingScene] = {}

    def warm_up(self, ids: Iterable[int]) -> None:
        """Build the scenes of ``ids`` now and cast a ray into each: Open3D builds a scene's
        BVH at its first query, which the first frame with that part would otherwise pay."""
        one_ray = o3d_tensor(np.array([[0, 0, -1, 0, 0, 1]], np.float32))
        for obj_id in ids:
            self[obj_id].cast_rays(one_ray)

    def __getitem__(self, obj_id: int) -> o3d.t.geometry.RaycastingScene:
        if obj_id not in self._scenes:
            self._scenes[obj_id] = raycasting_scene(*self.meshes[obj_id])
        return self._scenes[obj_id]


class LookalikeCheck:
    """Picks, among a part and its look-alikes, the one whose surface explains the ROI depth.

    Args:
        meshes: {obj_id: (vertices m, faces)} of the parts that have look-alikes.
        lookalikes: {obj_id: look-alike ids} (:func:`lookalike_pairs`).
        tolerance_m: see :func:`depth_vote`.
        min_z: a look-alike overturns the fitted class only by a clear margin of pixels
            (:func:`clear_margin`); 0: by any.

    The check runs at the pose fitted for the classifier's class, so the fitted pose limits
    what it can tell (``tlessbot bench recognition``; figures in docs/bench/code-figures.md).
    """

    def __init__(self, meshes: Mapping[int, Mesh], lookalikes: Mapping[int, tuple[int, ...]],
                 *, tolerance_m: float = 0.002, min_z: float = 0.0) -> None:
        self._scenes = MeshScenes(meshes)
        self.lookalikes = {int(k): tuple(int(i) for i in v) for k, v in lookalikes.items()
                           if all(i in self._scenes.meshes for i in (k, *v))}
        self.tolerance_m = float(tolerance_m)
        self.min_z = float(min_z)

    def __contains__(self, obj_id: object) -> bool:
        return obj_id in self.lookalikes

    def warm_up(self) -> None:
        """Build every part's ray-casting scene now instead of on first use
        (:meth:`MeshScenes.warm_up`)."""
        self._scenes.warm_up(self.lookalikes)

    def scene(self, obj_id: int) -> o3d.t.geometry.RaycastingScene:
        """The ray-casting scene of part ``obj_id``'s mesh (built on first use)."""
        return self._scenes[obj_id]

    def resolve(self, obj_id: int, T_camera_object: np.ndarray, points_c: np.ndarray, *,
                more_views: Sequence[tuple[np.ndarray, np.ndarray]] = (),
                T_world_camera: np.ndarray | None = None,
                refine: bool | Callable[[], bool] = False) -> tuple[int, float]:
        """(winner, its vote against ``obj_id``): ``obj_id`` itself (vote 0) unless a
        look-alike at the same pose explains the depth better by a clear margin (``min_z``,
        :func:`clear_margin`) of the pixels of every view given; with ``refine``, where that
        pose leaves the two open, each part votes again from its own pose near it.

        Args:
            obj_id: the class the pose was fitted for.
            T_camera_object: (4, 4) that fitted pose in the cloud's optical frame.
            points_c: (N, 3) ROI cloud, metres, optical frame.
            more_views: the part's ROI clouds in other cameras, each as ((M, 3) points in
                that camera's optical frame, (4, 4) ``T_other_camera``: the cloud's camera
                in that one); their pixels vote with those of ``points_c``.
            T_world_camera: (4, 4) the table frame of the cloud's camera (z = 0 on the
                table), or None: a pixel the mesh misses then expects the table behind
                (:func:`depth_errors`).
            refine: where the fitted pose gives neither part a clear margin, each (``obj_id``
                and that look-alike) moves to where its own surface explains the most pixels
                near it (:func:`refine_on_depth`), and they vote again from there. A callable
                is asked once, and only where the fitted pose leaves a pair open.

        Returns:
            the winner and its vote: the share of all the pixels that it explains better
            minus the share that ``obj_id`` explains better (0 when ``obj_id`` stays).
        """
        obj_id = int(obj_id)
        T0 = np.asarray(T_camera_object, np.float64)
        transforms = [np.eye(4)] + [np.asarray(T_other, np.float64) for _, T_other in more_views]
        clouds = [points_c] + [points for points, _ in more_views]
        planes = view_planes(T_world_camera, transforms[1:])
        views = [(T, points, plane) for T, points, plane in zip(transforms, clouds, planes)
                 if len(points)]
        if obj_id not in self.lookalikes or not views:
            return obj_id, 0.0

        def errors(part: int, refined: bool = False) -> list[np.ndarray]:
            vertices = np.asarray(self._scenes.meshes[part][0], np.float64)
            centre = (vertices.min(axis=0) + vertices.max(axis=0)) / 2
            T = refine_on_depth(self.scene(part), T0, views, self.tolerance_m, centre) \
                if refined else T0
            return [depth_errors(self.scene(part), T_view @ T, points, plane)
                    for T_view, points, plane in views]

        own, own_refined = errors(obj_id), None
        may_refine = refine if isinstance(refine, bool) else None   # None: not asked yet
        best, best_vote = obj_id, 0.0
        for other in self.lookalikes[obj_id]:
            theirs = errors(other)
            vote = pooled_vote(theirs, own, self.tolerance_m, self.min_z)
            if may_refine is not False and vote == 0.0 and \
                    pooled_vote(own, theirs, self.tolerance_m, self.min_z) == 0.0:
                # the fitted pose leaves the two open: each votes again from its own pose
                if may_refine is None:
                    may_refine = bool(cast(Callable[[], bool], refine)())
                if not may_refine:
                    continue
                if own_refined is None:
                    own_refined = errors(obj_id, refined=True)
                vote = pooled_vote(errors(other, refined=True), own_refined, self.tolerance_m,
                                   self.min_z)
            if vote > best_vote:
                best, best_vote = other, vote
        return best, best_vote


# (degrees, metres) of the coordinate steps of :func:`refine_on_depth`, coarse to fine: the
# fitted pose of a twin is a degree or a few off, its distinguishing holes a few pixels wide
_REFINE_STEPS = ((2.0, 0.001), (1.0, 0.0005), (0.5, 0.00025))


def explained_pixels(scene: o3d.t.geometry.RaycastingScene, T_camera_object: np.ndarray,
                     views: Sequence[tuple[np.ndarray, np.ndarray, np.ndarray | None]],
                     tolerance_m: float) -> int:
    """The pixels of every view whose depth a mesh at ``T_camera_object`` explains within
    ``tolerance_m`` (:func:`depth_errors`); ``views``: per view ((4, 4) the pose's camera
    into that view's, (N, 3) ROI cloud in that view's optical frame, its table plane (4,)
    or None)."""
    return sum(int(np.count_nonzero(depth_errors(scene, T_view @ T_camera_object, points, plane)
                                    <= tolerance_m))
               for T_view, points, plane in views)


def refine_on_depth(scene: o3d.t.geometry.RaycastingScene, T_camera_object: np.ndarray,
                    views: Sequence[tuple[np.ndarray, np.ndarray, np.ndarray | None]],
                    tolerance_m: float, centre_o: np.ndarray) -> np.ndarray:
    """(4, 4) the pose near ``T_camera_object`` at which the mesh explains the most pixels
    (:func:`explained_pixels`; ``views`` as there): a coordinate ascent over turns about the
    model's axes through ``centre_o`` (3,) (m, model frame) and shifts along them, of 2° and
    1 mm, then 1° and 0.5 mm, then 0.5° and 0.25 mm. A point-to-plane fit is blind to a
    few-millimetre hole, since its walls hold few of the model's points; the pixels that see
    through it are not."""
    T = np.array(T_camera_object, np.float64)
    score = explained_pixels(scene, T, views, tolerance_m)
    for step_deg, step_m in _REFINE_STEPS:
        moved = True
        while moved:
            moved = False
            for move in _steps(centre_o, step_deg, step_m):
                value = explained_pixels(scene, T @ move, views, tolerance_m)
                if value > score:
                    T, score, moved = T @ move, value, True
    return T


def _steps(centre_o: np.ndarray, step_deg: float, step_m: float) -> list[np.ndarray]:
    """The 12 moves (4, 4), model frame, of one ascent step: ± ``step_deg`` about each
    model axis through ``centre_o`` (3,), ± ``step_m`` along each."""
    import cv2

    moves = []
    for axis in range(3):
        for sign in (-1.0, 1.0):
            turn = np.eye(4)
            turn[:3, :3] = cv2.Rodrigues(np.eye(3)[axis] * sign * np.radians(step_deg))[0]
            turn[:3, 3] = centre_o - turn[:3, :3] @ centre_o
            shift = np.eye(4)
            shift[axis, 3] = sign * step_m
            moves += [turn, shift]
    return moves
