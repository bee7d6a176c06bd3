"""A scripted table for the arm's side: parts rest for a while, then some move, one is added
and one removed, and the new layout rests again.

:func:`scripted_table` draws the first layout (``parts`` parts of ``classes``; more parts than
classes gives two parts of one class) and the second from it; each part keeps a ``key`` while
it stays where it is, so a test knows which names must hold. :func:`script_frames` renders the
frames: the table and light stay those of frame 0, the sensor noise is each frame's own.
"""
from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field

import numpy as np

from tlessbot_ros.sim.scene import (
    PlacedObject,
    SceneParams,
    hull_info,
    placement_fits,
    sample_scene,
    work_area_centre,
)
from tlessbot_ros.sim.simulator import SimulatedFrame, Simulator

__all__ = ['ScriptParams', 'ScriptedTable', 'script_frames', 'scripted_table']


@dataclass(frozen=True)
class ScriptParams:
    """The script: ``rest_frames`` of the first layout, then ``change_frames`` of the second,
    in which ``moved`` parts moved by ``move_m`` (metres, on the table), ``removed`` parts are
    gone and ``added`` parts came."""

    rest_frames: int = 6
    change_frames: int = 6
    parts: int = 4
    moved: int = 1
    removed: int = 1
    added: int = 1
    move_m: float = 0.08

    def __post_init__(self) -> None:
        if self.rest_frames < 1 or self.change_frames < 0:
            raise ValueError('rest_frames must be >= 1 and change_frames >= 0')
        if self.parts < 1 or self.moved + self.removed > self.parts:
            raise ValueError(f'need parts >= 1 and moved + removed <= parts, got parts '
                             f'{self.parts}, moved {self.moved}, removed {self.removed}')


@dataclass
class ScriptedTable:
    """The two layouts. ``keys[k][i]`` names part ``i`` of layout ``k``; a part that stayed
    keeps its key, a moved part gets a new one (``<key>'``)."""

    layouts: list[list[PlacedObject]]
    keys: list[list[str]]
    moved: list[str] = field(default_factory=list)
    removed: list[str] = field(default_factory=list)
    added: list[str] = field(default_factory=list)

    def layout_of_frame(self, index: int, params: ScriptParams) -> int:
        return 0 if index < params.rest_frames else 1


def scripted_table(sim: Simulator, params: ScriptParams = ScriptParams(), *,
                   seed: int = 0) -> ScriptedTable:
    """Draw the script's two layouts for ``sim``'s models and rig (deterministic in ``seed``).

    Raises:
        ValueError: no free place for a moved or added part in 200 tries.
    """
    rng = np.random.default_rng([seed, 42])
    scene = SceneParams(parts_min=params.parts, parts_max=params.parts, unique_classes=False,
                        cluster_prob=0.0, area_radius_m=0.15)
    first = sample_scene(sim.models, sim.rig, rng, scene, materials=tuple(sim.params.materials))
    keys = [chr(ord('a') + i) for i in range(len(first))]
    second, second_keys = list(first), list(keys)
    table = ScriptedTable([first, second], [keys, second_keys])
    for _ in range(params.removed):
        k = len(second) - 1
        table.removed.append(second_keys.pop(k))
        second.pop(k)
    for k in range(params.moved):
        others = second[:k] + second[k + 1:]
        second[k] = _moved(sim, second[k], others, params.move_m, rng)
        table.moved.append(second_keys[k])
        second_keys[k] += "'"
    for n in range(params.added):
        obj_id = int(rng.choice(sorted(sim.models)))
        second.append(_placed(sim, obj_id, second, rng))
        second_keys.append(chr(ord('a') + len(first) + n))
        table.added.append(second_keys[-1])
    return table


def script_frames(sim: Simulator, table: ScriptedTable, params: ScriptParams
                  ) -> Iterator[SimulatedFrame]:
    """Render the script's frames in order."""
    for index in range(params.rest_frames + params.change_frames):
        layout = table.layouts[table.layout_of_frame(index, params)]
        yield sim.frame_of(index, layout, environment=0)


def _fits(sim: Simulator, obj_id: int, T: np.ndarray, others: list[PlacedObject]) -> bool:
    samples = sim.params.scene_params.hull_samples
    return placement_fits(
        hull_info(sim.models[obj_id], samples), T, sim.rig,
        [(hull_info(sim.models[o.obj_id], samples), o.T_world_object) for o in others],
        margin_px=sim.params.scene_params.margin_px, touch_tol_m=0.002)


def _moved(sim: Simulator, part: PlacedObject, others: list[PlacedObject], move_m: float,
           rng: np.random.Generator) -> PlacedObject:
    for _ in range(200):
        angle = rng.uniform(-np.pi, np.pi)
        T = part.T_world_object.copy()
        T[:2, 3] += move_m * np.array([np.cos(angle), np.sin(angle)])
        if _fits(sim, part.obj_id, T, others):
            return PlacedObject(part.obj_id, T, part.material)
    raise ValueError(f'no free place {move_m} m away for obj_{part.obj_id:02d}')


def _placed(sim: Simulator, obj_id: int, others: list[PlacedObject],
            rng: np.random.Generator) -> PlacedObject:
    centre = work_area_centre(sim.rig)
    single = SceneParams(parts_min=1, parts_max=1, area_radius_m=0.15)
    for _ in range(200):
        candidate = sample_scene({obj_id: sim.models[obj_id]}, sim.rig, rng, single,
                                 materials=tuple(sim.params.materials))
        if candidate and _fits(sim, obj_id, candidate[0].T_world_object, others) and \
                np.linalg.norm(candidate[0].T_world_object[:2, 3] - centre) <= 0.15:
            return candidate[0]
    raise ValueError(f'no free place for an added obj_{obj_id:02d}')
