"""Whether the rig can resolve a part's pose where it lies in a scene, from the truth alone.

:mod:`.observability` measures what the rig sees of a part's turns in its resting poses,
alone on the table. Here the part is at its true pose in a scene, the other parts hide what
they hide, and the truth is compared in every camera with each turn
:func:`~.observability.measured_turns` lists (by ``turn_deg`` about its axes and the vertical;
half turns about its model axes and the vertical that are no listed symmetry: end for end, its
face turned away from a camera) and with each look-alike twin at the same pose
(:func:`~.observability.changed_pixels`: depth beyond ``noise_sigmas`` of the D415 model, or a
rendered edge moved by more than ``edge_px``). A turn that keeps the part at rest and changes
fewer than ``min_px`` pixels, or a twin that changes fewer, cannot be told from the truth by
any pose stage: the instance is unresolvable at ``turn_deg``. A turn that lifts the part off
the table is no doubt (the pose stage levels it). No estimate is used: this is a property of
the scene and the rig.
"""
from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from tlessbot_ros.core.common import raycasting_scene, transform_points
from tlessbot_ros.core.pose.observability import (
    ObservabilityParams,
    ViewOfTable,
    changed_pixels,
    measured_turns,
    turn_at_pose,
)

if TYPE_CHECKING:
    import open3d as o3d

# the causes an instance is unresolvable by, in the order reports list them
CAUSES = ('turn', 'half turn', 'twin')


@dataclass(frozen=True)
class PartShape:
    """What the measure needs of one part.

    Attributes:
        scene: its mesh in its model frame (an Open3D ``RaycastingScene``, metres).
        points: (N, 3) samples of its surface, model frame, metres.
        centre: (3,) the point turns are about (its centre of mass).
        listed: its listed discrete symmetries ((4, 4) or (3, 3)).
        continuous_axes: model-frame axes it turns about onto itself.
    """

    scene: o3d.t.geometry.RaycastingScene
    points: np.ndarray
    centre: np.ndarray
    listed: Sequence[np.ndarray] = ()
    continuous_axes: Sequence[np.ndarray] = ()


@dataclass(frozen=True)
class Resolvability:
    """What the rig sees of the doubts about one instance's true pose: the turns that keep it
    at rest ``(axis name, angle in degrees, pixels changed)`` and its look-alike twins
    ``(obj_id, pixels changed)``; those that change fewer than ``min_px`` pixels are unseen."""

    turns: tuple[tuple[str, float, int], ...] = field(default_factory=tuple)
    twins: tuple[tuple[int, int], ...] = field(default_factory=tuple)
    min_px: int = ObservabilityParams.min_px

    @property
    def unseen_turns(self) -> tuple[tuple[str, float, int], ...]:
        return tuple(t for t in self.turns if t[2] < self.min_px)

    @property
    def unseen_twins(self) -> tuple[tuple[int, int], ...]:
        return tuple(t for t in self.twins if t[1] < self.min_px)

    @property
    def causes(self) -> tuple[str, ...]:
        """Of :data:`CAUSES`, those that make this instance unresolvable."""
        found = {'half turn' if angle >= 90.0 else 'turn' for _, angle, _ in self.unseen_turns}
        if self.unseen_twins:
            found.add('twin')
        return tuple(c for c in CAUSES if c in found)

    @property
    def resolvable(self) -> bool:
        return not self.unseen_turns and not self.unseen_twins


def posed_scene(meshes: Sequence[tuple[np.ndarray, np.ndarray, np.ndarray]]
                ) -> o3d.t.geometry.RaycastingScene | None:
    """One ray-casting scene, world frame, of meshes ``(vertices (V, 3) m, faces (F, 3),
    T_world_object (4, 4))`` at their poses; None when there are none."""
    if not meshes:
        return None
    vertices, faces, offset = [], [], 0
    for v, f, T in meshes:
        vertices.append(transform_points(np.asarray(T, np.float64), np.asarray(v, np.float64)))
        faces.append(np.asarray(f, np.int64) + offset)
        offset += len(v)
    return raycasting_scene(np.vstack(vertices), np.vstack(faces))


def resolvability(part: PartShape, T_world_object: np.ndarray, views: Sequence[ViewOfTable],
                  params: ObservabilityParams, *,
                  others: o3d.t.geometry.RaycastingScene | None = None,
                  twins: Mapping[int, PartShape] | None = None) -> Resolvability:
    """The turns and twins the rig cannot tell from ``part`` at ``T_world_object`` (its true
    pose on the table, z = 0, metres).

    Args:
        part: the part (:class:`PartShape`).
        T_world_object: (4, 4) its true pose.
        views: the rig's cameras.
        params: the measure's settings (``turn_deg``, the noise model, ``edge_px``,
            ``min_px``, ``rest_ratio``).
        others: the other parts of the scene at their poses (:func:`posed_scene`), that hide
            it where nearer; None: alone on the table.
        twins: its look-alike parts by id (sharing its model frame), compared at its pose.
    """
    turns = []
    up_o = np.asarray(T_world_object, np.float64)[2, :3]    # the vertical, model frame
    for name, axis, angle in measured_turns(part.points, params,
                                            continuous_axes=part.continuous_axes,
                                            listed=part.listed, up_o=up_o):
        found = turn_at_pose(part.scene, part.points, part.centre, T_world_object, views,
                             params, axis, angle, continuous_axes=part.continuous_axes,
                             others=others, at_rest_only=True)
        if found is not None and found[1]:
            turns.append((name, angle, int(found[0][2])))
    twin_px = []
    for obj_id, twin in (twins or {}).items():
        points = np.vstack([part.points, twin.points])     # the window covers both
        changed = sum(changed_pixels(part.scene, points, T_world_object, T_world_object, view,
                                     params, scene_b=twin.scene, others=others)[2]
                      for view in views)
        twin_px.append((int(obj_id), int(changed)))
    return Resolvability(tuple(turns), tuple(twin_px), params.min_px)


__all__ = ['CAUSES', 'PartShape', 'Resolvability', 'posed_scene', 'resolvability']
