"""``tlessbot parts build``'s check of what the rig can see: per part, the axes about which a
turn by 5° (or a half turn, end for end) that leaves it at rest changes fewer than ``min_px``
pixels in the rig's cameras, the part resting on the table at the centre of the work area
(:mod:`tlessbot_ros.core.pose.observability`). There no pose stage can hold the part within
5°: the features that tell the turn are small against a pixel."""
from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from tlessbot_ros.core.common import Rig, Symmetries
    from tlessbot_ros.core.pose import AxisVisibility, ObservabilityParams
    from tlessbot_ros.core.pose.resolvability import PartShape
    from tlessbot_ros.io.models import ObjectModel

SAMPLES = 3000          # surface samples a part's window and centre are taken from


def part_turns(model: ObjectModel, rig: Rig,
               params: ObservabilityParams | None = None) -> list[AxisVisibility]:
    """What every camera of ``rig`` sees of ``model`` turned by ``params.turn_deg`` about each
    of its axes, in its most probable resting poses (:func:`~tlessbot_ros.core.pose.
    observability.turn_visibility`; axes of its listed continuous symmetries left out)."""
    from tlessbot_ros.core.pose import (
        ObservabilityParams,
        ViewOfTable,
        turn_visibility,
    )
    from tlessbot_ros.io.models import stable_poses

    params = params or ObservabilityParams()
    shape = part_shape(model)
    resting = [(p.T_table_object, p.probability)
               for p in stable_poses(model, merge_rolling=True)]
    views = [ViewOfTable(cam.intrinsics, cam.T_world_camera) for cam in rig.cameras.values()]
    return turn_visibility(shape.scene, shape.points, resting, views, params,
                           continuous_axes=shape.continuous_axes, listed=shape.listed,
                           centre=shape.centre)


def part_shape(model: ObjectModel, symmetries: Symmetries | None = None) -> PartShape:
    """What the measures of :mod:`~tlessbot_ros.core.pose.observability` need of ``model``:
    its mesh, ``SAMPLES`` surface samples, its centre of mass and its listed symmetries (or
    ``symmetries``: those a scorer uses)."""
    from tlessbot_ros.core.common import raycasting_scene, sample_surface
    from tlessbot_ros.core.common.resting import centre_of_mass
    from tlessbot_ros.core.pose.resolvability import PartShape

    if symmetries is None:
        listed = tuple(model.symmetries_discrete or ())
        axes = tuple(c['axis'] for c in model.symmetries_continuous or ())
    else:
        listed = tuple(symmetries.discrete)
        axes = tuple(axis for axis, _ in symmetries.continuous)
    return PartShape(raycasting_scene(model.vertices, model.faces),
                     sample_surface(model.vertices, model.faces, SAMPLES, seed=0)[0],
                     centre_of_mass(model.vertices, model.faces), listed=listed,
                     continuous_axes=axes)


def unseen_turns(axes: list[AxisVisibility]) -> dict:
    """The manifest's record of a part's unseen turns: ``axes`` (name, pixels changed in the
    median resting pose: all, depth, edges) where most of the resting poses' probability sees
    too few, and ``every_axis`` when that is every axis measured."""
    unseen = [{'axis': a.axis, 'turn_deg': a.turn_deg, 'changed_px': round(a.changed_px),
               'depth_px': round(a.depth_px), 'edge_px': round(a.edge_px)}
              for a in axes if a.unseen_share >= 0.5]
    return {'axes': unseen, 'every_axis': bool(unseen) and len(unseen) == len(axes)}


def unseen_note(record: dict | None) -> str:
    """A self-check table cell: '-' (every turn is seen), 'y (9 px)' (5° about the model's y),
    'yaw (2 px), x 180° (6 px)' (and a half turn about x), or 'every turn (<= 4 px)'."""
    if not record or not record['axes']:
        return '-'
    if record['every_axis']:
        return f"every turn (≤ {max(a['changed_px'] for a in record['axes'])} px)"
    return ', '.join(f"{a['axis']}{' 180°' if a.get('turn_deg', 5.0) > 90 else ''} "
                     f"({a['changed_px']} px)" for a in record['axes'])


def record_unseen_turns(models_dir: Path, entries: list[dict], rig: Rig, *,
                        quiet: bool = False) -> None:
    """Each manifest entry's ``unseen_turns_5deg`` (:func:`unseen_turns`), from the models of
    ``models_dir``; prints the parts with any (not ``quiet``)."""
    from tlessbot_ros.core.pose import ObservabilityParams
    from tlessbot_ros.io.models import load_models

    params = ObservabilityParams()
    models = load_models(models_dir)
    for entry in entries:
        record = unseen_turns(part_turns(models[entry['id']], rig, params))
        entry['unseen_turns_5deg'] = record
        if record['axes'] and not quiet:
            print(f"[parts build] {entry['name']}: the rig's views change by fewer than "
                  f"{params.min_px} pixels for a turn by 5° (or 180°) about "
                  f"{unseen_note(record)}: the cell cannot hold its pose to 5° there")


__all__ = ['part_turns', 'record_unseen_turns', 'unseen_note', 'unseen_turns']
