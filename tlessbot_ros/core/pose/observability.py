"""What the rig can see of a turn of a part: pixels that change when it turns.

A pose error is only found if it shows in the cameras. Turning a part by a few degrees about
an axis moves its outline, its creases and its depth; a part whose features are small against
a pixel (a nozzle's slots a millimetre wide, seen at 1 mm a pixel) barely changes when turned
about its own axis, and no pose stage can tell the turn from the true pose. This measures it
before the cell runs: the part is rendered noise-free on the table in every camera of the rig,
at the pose and turned by ``turn_deg`` about an axis through its centre, and two kinds of
pixels are counted: those whose depth moves by more than ``noise_sigmas`` times the stereo
depth noise at that distance (sigma = ``noise_at_1m_m`` * z^2, the D415 model of the
simulator), and the colour-edge pixels (outline, depth steps and creases, as the turn check
renders them: :func:`~.turns.rendered_edges`) that have no edge of the other render within
``edge_px``. A pixel counts once if it changes both ways. The half turns about the model axes
that are no listed symmetry are measured too (a hex nut turned end for end: its chamfers
differ by half a millimetre). The turned part is seated on the table again; only turns that
keep it at rest count (a tilt off a face the pose stage levels away: :mod:`.resting`).
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from tlessbot_ros.core.common import CameraIntrinsics, rotation_about_axis
from tlessbot_ros.core.pose.fallback import turn_axes
from tlessbot_ros.core.pose.flat_turns import turn_about
from tlessbot_ros.core.pose.silhouette import window, window_depth
from tlessbot_ros.core.pose.turns import rendered_edges

if TYPE_CHECKING:
    import open3d as o3d


@dataclass(frozen=True)
class ObservabilityParams:
    """Settings of :func:`turn_visibility`.

    Attributes:
        turn_deg: the turn measured (0 < turn < 90): the pose tolerance of the scoring, 5°.
        noise_at_1m_m: the depth noise (one sigma) at 1 m; it grows with the square of the
            distance (stereo). 2.1 mm: the simulator's D415 model.
        noise_sigmas: a depth change counts when larger than this many sigmas (> 0).
        edge_px: an edge pixel moved when the other render has no edge within this, px (> 0).
        min_px: a turn is seen when at least this many pixels change, all cameras (>= 1).
        poses: the most probable resting poses measured (>= 1).
        rest_ratio: a turn keeps the part at rest when it lifts the part's centre (seated
            on the table again) by at most this share of its size times sin(turn) (0..1):
            a roll on a round side lifts it by nothing, a tilt off a face by its distance to
            the edge; a tilt the stage levels onto the resting pose (:mod:`.resting`).
        jump_m, crease_deg: what makes a rendered edge (:class:`~.turns.TurnParams`).
    """

    turn_deg: float = 5.0
    noise_at_1m_m: float = 0.0021
    noise_sigmas: float = 3.0
    edge_px: float = 1.0
    min_px: int = 20
    poses: int = 4
    rest_ratio: float = 0.02
    jump_m: float = 0.002
    crease_deg: float = 30.0

    def __post_init__(self) -> None:
        if not 0.0 < self.turn_deg < 90.0 or self.noise_at_1m_m <= 0.0 or \
                self.noise_sigmas <= 0.0 or self.edge_px <= 0.0:
            raise ValueError('turn_deg must be in (0, 90); noise_at_1m_m, noise_sigmas and '
                             f'edge_px > 0; got {self.turn_deg}, {self.noise_at_1m_m}, '
                             f'{self.noise_sigmas}, {self.edge_px}')
        if not 0.0 <= self.rest_ratio <= 1.0:
            raise ValueError(f'rest_ratio must be in [0, 1], got {self.rest_ratio}')
        if self.min_px < 1 or self.poses < 1:
            raise ValueError(f'min_px and poses must be >= 1, got {self.min_px}, {self.poses}')


@dataclass(frozen=True)
class ViewOfTable:
    """One camera of the rig: its intrinsics and ``T_world_camera`` (optical frame; the
    table is the world plane z = 0)."""

    intrinsics: CameraIntrinsics
    T_world_camera: np.ndarray


def changed_pixels(scene: o3d.t.geometry.RaycastingScene, points: np.ndarray,
                   T_world_a: np.ndarray, T_world_b: np.ndarray, view: ViewOfTable,
                   params: ObservabilityParams, *,
                   scene_b: o3d.t.geometry.RaycastingScene | None = None,
                   others: o3d.t.geometry.RaycastingScene | None = None
                   ) -> tuple[int, int, int]:
    """(depth, edge, either) pixels of ``view`` that tell the part at ``T_world_a`` from the
    part at ``T_world_b`` (world poses on the table; ``scene`` its mesh and ``points`` (N, 3)
    its surface samples in the model frame, metres). ``scene_b``: the mesh at ``T_world_b``
    when it is another part (a look-alike twin; ``points`` then cover both). ``others``: the
    other parts of the scene, one mesh in the world frame, that hide the part where nearer
    (None: the part alone on the table); an edge hidden in a render is not seen to move."""
    import cv2

    T_camera_world = np.linalg.inv(view.T_world_camera)
    poses = [T_camera_world @ T_world_a, T_camera_world @ T_world_b]
    box = window(points, poses, view.intrinsics, margin_px=3)
    if box is None:
        return 0, 0, 0
    meshes = (scene, scene if scene_b is None else scene_b)
    rays, depth_a = window_depth(meshes[0], poses[0], view.intrinsics, box)
    depth_b = window_depth(meshes[1], poses[1], view.intrinsics, box)[1]
    R, origin = view.T_world_camera[:3, :3], view.T_world_camera[:3, 3]
    down = rays @ R.T[:, 2]                       # world z per unit of depth along each ray
    with np.errstate(divide='ignore'):
        table = np.where(down < 0, -origin[2] / down, np.inf)
    shown = [np.ones((box[3], box[2]), bool)] * 2
    if others is not None:
        front = window_depth(others, T_camera_world, view.intrinsics, box)[1]
        shown = [~(front < d).reshape(box[3], box[2]) for d in (depth_a, depth_b)]
        depth_a, depth_b = np.minimum(depth_a, front), np.minimum(depth_b, front)
    depth_a = np.where(np.isfinite(depth_a), depth_a, table)
    depth_b = np.where(np.isfinite(depth_b), depth_b, table)
    near = np.minimum(depth_a, depth_b)
    noise = params.noise_sigmas * params.noise_at_1m_m * near ** 2
    with np.errstate(invalid='ignore'):
        depth_moved = (np.abs(depth_a - depth_b) > noise).reshape(box[3], box[2])
    edges = [rendered_edges(mesh, T, view.intrinsics, box, jump_m=params.jump_m,
                            crease_deg=params.crease_deg) for mesh, T in zip(meshes, poses)]
    moved = np.zeros_like(edges[0])
    for mine, other, seen in ((edges[0], edges[1], shown[0]), (edges[1], edges[0], shown[1])):
        distance = cv2.distanceTransform((~other).astype(np.uint8), cv2.DIST_L2, 3)
        moved |= mine & seen & (distance > params.edge_px)
    return (int(np.count_nonzero(depth_moved)), int(np.count_nonzero(moved)),
            int(np.count_nonzero(depth_moved | moved)))


def turned(T_world_object: np.ndarray, axis_o: np.ndarray, centre_o: np.ndarray,
           angle_deg: float) -> np.ndarray:
    """``T_world_object`` turned by ``angle_deg`` about the model-frame ``axis_o`` through the
    model-frame point ``centre_o``."""
    turn = turn_about(np.asarray(axis_o, np.float64), np.radians(angle_deg),
                      np.asarray(centre_o, np.float64))
    out: np.ndarray = np.asarray(T_world_object, np.float64) @ turn
    return out


def axis_name(axis: np.ndarray) -> str:
    """'x', 'y' or 'z' for a model axis (either sign), else the axis rounded, as text."""
    for k, name in enumerate('xyz'):
        if abs(abs(axis[k]) - 1.0) < 1e-6:
            return name
    return '(' + ' '.join(f'{a:.2f}' for a in axis) + ')'


@dataclass(frozen=True)
class AxisVisibility:
    """A turn about one axis: its name ('x', 'y', 'z': model axes; a principal axis as a
    vector; 'yaw': the vertical of each resting pose), the pixels it changes in the median
    resting pose (weighted by probability; depth, edges, either), the share of the resting
    poses' probability where it keeps the part at rest (a yaw, a roll on a round side, a half
    turn onto a face alike: the table does not settle it), the share where it does and fewer
    than ``min_px`` pixels change (the turn is not seen), and the turn's angle."""

    axis: str
    depth_px: float
    edge_px: float
    changed_px: float
    resting_share: float
    unseen_share: float
    turn_deg: float = 5.0


def _weighted_median(values: np.ndarray, weights: np.ndarray) -> float:
    order = np.argsort(values)
    cumulative = np.cumsum(weights[order])
    return float(values[order][np.searchsorted(cumulative, 0.5 * cumulative[-1])])


def _is_symmetry(R: np.ndarray, listed: Sequence[np.ndarray],
                continuous_axes: Sequence[np.ndarray]) -> bool:
    """Whether the rotation ``R`` is a listed symmetry, or one composed with a turn about a
    continuous axis."""
    from tlessbot_ros.core.common import rotation_angle_deg

    for L in [np.eye(3), *listed]:
        M = R @ np.asarray(L, np.float64)[:3, :3].T
        if rotation_angle_deg(M, np.eye(3)) < 1.0:
            return True
        values, vectors = np.linalg.eig(M)
        axis = np.real(vectors[:, int(np.argmin(np.abs(values - 1.0)))])   # a half turn too
        if any(abs(float(axis @ c)) > np.cos(np.radians(5.0)) for c in continuous_axes):
            return True
    return False


def turn_visibility(scene: o3d.t.geometry.RaycastingScene, points: np.ndarray,
                    resting: Sequence[tuple[np.ndarray, float]], views: Sequence[ViewOfTable],
                    params: ObservabilityParams, *, continuous_axes: Sequence[np.ndarray] = (),
                    listed: Sequence[np.ndarray] = (), centre: np.ndarray | None = None
                    ) -> list[AxisVisibility]:
    """How well the rig sees a turn by ``params.turn_deg`` of a part resting on the table, and
    its half turns (end for end) that are no listed symmetry.

    Args:
        scene: the part's mesh in its model frame (an Open3D ``RaycastingScene``, metres).
        points: (N, 3) samples of its surface, model frame.
        resting: its resting poses ``(T_table_object, probability)`` (the table's origin seen
            by the rig: :func:`~tlessbot_ros.core.common.resting.resting_poses`); the
            ``params.poses`` most probable are measured.
        views: the rig's cameras.
        params: the settings.
        continuous_axes: model-frame axes the part turns about onto itself (left out).
        listed: its listed discrete symmetries ((3, 3) or (4, 4); half turns that are one of
            them are left out).
        centre: (3,) the point the turns are about (its centre of mass: a half turn about
            an axis through it maps a part symmetric end for end onto itself); None: the
            samples' mean.

    Returns:
        one :class:`AxisVisibility` per turn: about the model axes and the principal axes of
        the samples (:func:`~.fallback.turn_axes`), 'yaw' (about the vertical), then the
        half turns about the model axes ('x', 'y', 'z' with ``turn_deg`` 180).
    """
    points = np.asarray(points, np.float64)
    centre = points.mean(axis=0) if centre is None else np.asarray(centre, np.float64)
    best = sorted(resting, key=lambda rp: -rp[1])[:params.poses]
    out = []
    for name, axis, angle in measured_turns(points, params, continuous_axes=continuous_axes,
                                            listed=listed):
        found = _one_turn(scene, points, centre, best, views, params, axis, angle,
                          continuous_axes)
        if found is not None:
            depth_px, edge_px, changed_px, rest_share, unseen = found
            out.append(AxisVisibility(name, depth_px, edge_px, changed_px, rest_share, unseen,
                                      turn_deg=angle))
    return out


def measured_turns(points: np.ndarray, params: ObservabilityParams, *,
                   continuous_axes: Sequence[np.ndarray] = (),
                   listed: Sequence[np.ndarray] = (), up_o: np.ndarray | None = None
                   ) -> list[tuple[str, np.ndarray | None, float]]:
    """The turns :func:`turn_visibility` measures, ``(name, model-frame axis or None for the
    vertical, angle in degrees)``: by ``params.turn_deg`` about the model and principal axes of
    the (N, 3) ``points`` but a continuous symmetry axis, about the vertical, then the half
    turns about the model axes that are no listed symmetry; with ``up_o`` (the vertical in the
    model frame of one pose) also the half turn about the vertical, unless a symmetry."""
    cos5 = np.cos(np.radians(5.0))
    turns: list[tuple[str, np.ndarray | None, float]] = [
        (axis_name(a), a, params.turn_deg) for a in turn_axes(np.asarray(points, np.float64))
        if all(abs(float(a @ c)) < cos5 for c in continuous_axes)]
    turns.append(('yaw', None, params.turn_deg))
    turns += [(axis_name(a), a, 180.0) for a in np.eye(3)
              if not _is_symmetry(rotation_about_axis(a, np.pi), listed, continuous_axes)]
    if up_o is not None and not _is_symmetry(
            rotation_about_axis(np.asarray(up_o, np.float64), np.pi), listed, continuous_axes):
        turns.append(('yaw', None, 180.0))
    return turns


def turn_at_pose(scene: o3d.t.geometry.RaycastingScene, points: np.ndarray,
                 centre: np.ndarray, T_world: np.ndarray, views: Sequence[ViewOfTable],
                 params: ObservabilityParams, axis: np.ndarray | None, angle: float, *,
                 continuous_axes: Sequence[np.ndarray] = (),
                 others: o3d.t.geometry.RaycastingScene | None = None,
                 at_rest_only: bool = False) -> tuple[np.ndarray, bool] | None:
    """The part at ``T_world`` (on the table) turned by ``angle`` about the model-frame
    ``axis`` (None: the vertical) through ``centre`` and seated on the table again: the
    (depth, edge, either) pixels it changes, all ``views`` (:func:`changed_pixels`, ``others``
    hiding it; not counted, zeros, for a turn off rest with ``at_rest_only``), and whether the
    turn keeps it at rest (``params.rest_ratio``). None for a yaw of a part standing on its
    round end (it maps the part onto itself)."""
    T = np.asarray(T_world, np.float64)
    up_o = T[2, :3]                                 # the world's z in the model frame
    if axis is None and any(abs(float(up_o @ c)) > np.cos(np.radians(5.0))
                            for c in continuous_axes):
        return None
    lift = params.rest_ratio * float(np.linalg.norm(np.ptp(points, axis=0))) * \
        np.sin(np.radians(min(angle, 90.0)))
    T_b = turned(T, up_o if axis is None else axis, centre, angle)
    heights = [float((points @ A[2, :3] + A[2, 3]).min()) for A in (T, T_b)]
    T_b[2, 3] += heights[0] - heights[1]                # seated: the centre moves by this
    rests = abs(heights[0] - heights[1]) <= lift
    if at_rest_only and not rests:
        return np.zeros(3, int), False
    counts = np.sum([changed_pixels(scene, points, T, T_b, view, params, others=others)
                     for view in views], axis=0)
    return counts, rests


def _one_turn(scene: o3d.t.geometry.RaycastingScene, points: np.ndarray, centre: np.ndarray,
              best: Sequence[tuple[np.ndarray, float]], views: Sequence[ViewOfTable],
              params: ObservabilityParams, axis: np.ndarray | None, angle: float,
              continuous_axes: Sequence[np.ndarray]
              ) -> tuple[float, float, float, float, float] | None:
    """:class:`AxisVisibility`'s figures of one turn (``axis`` None: the vertical), None when
    it maps every pose onto itself. The turned part is seated on the table again."""
    weights = np.array([p for _, p in best], np.float64)
    counts = np.full((len(best), 3), np.nan)
    rests = np.zeros(len(best), bool)
    for k, (T, _) in enumerate(best):
        found = turn_at_pose(scene, points, centre, T, views, params, axis, angle,
                             continuous_axes=continuous_axes)
        if found is not None:
            counts[k], rests[k] = found
    measured = ~np.isnan(counts[:, 0])
    if not measured.any():
        return None
    c, w, r = counts[measured], weights[measured], rests[measured]
    depth_px, edge_px, changed_px = (_weighted_median(c[:, j], w) for j in range(3))
    return (depth_px, edge_px, changed_px, float(w[r].sum() / w.sum()),
            float(w[r & (c[:, 2] < params.min_px)].sum() / w.sum()))


__all__ = ['AxisVisibility', 'ObservabilityParams', 'ViewOfTable', 'axis_name',
           'changed_pixels', 'measured_turns', 'turn_at_pose', 'turn_visibility', 'turned']
