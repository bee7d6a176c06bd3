"""A simulated capture session: one part on a turntable in the cell, seen by the cell's cameras.

What ``tlessbot capture`` records on a real cell, rendered: the part rests on a plate at the
middle of the work area (where both cameras look), in one of its stable poses (drawn with its
drop probability), ``position_radius_m`` off the plate's axis at one of ``positions`` places
(the paper's four), and the plate turns ``step_deg`` per frame. After each full turn (or every
``frames / positions`` frames when a session has fewer) the part is laid again at the next
place, as the paper's operator did. Table, light and the part's material stay the same for the
whole session (one part, one cell, one afternoon); the sensor noise changes every frame.

The bag holds the cameras' topics only (colour, aligned depth and both camera_infos, as the
drivers publish them) and the label ``capture.yaml`` (:mod:`tlessbot_ros.io.capture`): the same
folder ``tlessbot capture`` writes, so training reads both alike.
"""
from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tlessbot_ros.core.common import make_transform, rotation_about_axis, transform_points
from tlessbot_ros.io.capture import CaptureLabel
from tlessbot_ros.io.models import stable_poses
from tlessbot_ros.sim.bag import BagParams, write_bag
from tlessbot_ros.sim.scene import PlacedObject, work_area_centre
from tlessbot_ros.sim.simulator import SimulatedFrame, Simulator

BACKGROUND_BAG = 'background'   # the empty table's bag, inside a simulated capture's folder


@dataclass(frozen=True)
class CaptureSessionParams:
    """A simulated capture session.

    Attributes:
        frames: frames in the session.
        step_deg: plate rotation between frames (degrees; the paper: 1).
        positions: places of the part on the plate over the session (the paper: 4).
        position_radius_m: distance of those places from the plate's axis (metres).
        material: the part's material (a name of ``sim.materials.MATERIALS``; '' = drawn
            once per session).
    """

    frames: int = 90
    step_deg: float = 4.0
    positions: int = 4
    position_radius_m: float = 0.03
    material: str = ''

    def __post_init__(self) -> None:
        if self.frames < 1:
            raise ValueError(f'frames must be at least 1, got {self.frames}')
        if not 0.0 < self.step_deg <= 360.0:
            raise ValueError(f'step_deg must be in (0, 360], got {self.step_deg}')
        if self.positions < 1:
            raise ValueError(f'positions must be at least 1, got {self.positions}')

    @property
    def frames_per_position(self) -> int:
        full_turn = int(round(360.0 / self.step_deg))
        return max(1, min(full_turn, -(-self.frames // self.positions)))


def capture_session(simulator: Simulator, obj_id: int, *,
                    params: CaptureSessionParams = CaptureSessionParams(),
                    seed: int = 0) -> Iterator[tuple[SimulatedFrame, float]]:
    """The frames of one part's session, each with its plate angle (degrees).

    Deterministic given the simulator's seed and ``seed``; frame ``i`` uses the simulator's
    frame index ``seed * 100000 + i`` (its noise), and the table and light of index
    ``seed * 100000``.
    """
    from tlessbot_ros.sim.materials import MATERIALS

    if obj_id not in simulator.models:
        raise ValueError(f"obj_id {obj_id} is not among the simulator's models "
                         f'{sorted(simulator.models)}')
    model = simulator.models[obj_id]
    rng = np.random.default_rng([seed, obj_id, 7])
    material = params.material or simulator.params.materials[
        int(rng.integers(len(simulator.params.materials)))]
    if material not in MATERIALS:
        raise ValueError(f'unknown material {material!r}; choose from {sorted(MATERIALS)}')
    poses = stable_poses(model)
    probs = np.array([p.probability for p in poses])
    probs /= probs.sum()
    centre = np.append(work_area_centre(simulator.rig), 0.0)
    base = seed * 100_000
    per = params.frames_per_position
    resting = None
    for i in range(params.frames):
        position, step = divmod(i, per)
        if step == 0:
            # the operator lays the part again: a new resting pose, at the next place
            T_rest = poses[int(rng.choice(len(poses), p=probs))].T_table_object
            middle = transform_points(T_rest, model.vertices).mean(axis=0)
            phi = 2.0 * np.pi * (position % params.positions) / params.positions
            offset = params.position_radius_m * np.array([np.cos(phi), np.sin(phi), 0.0])
            resting = make_transform(np.eye(3), offset - middle * [1, 1, 0]) @ T_rest
        angle = (step * params.step_deg + rng.uniform(0.0, params.step_deg)) % 360.0
        plate = make_transform(rotation_about_axis(np.array([0.0, 0.0, 1.0]),
                                                   np.radians(angle)), centre)
        placed = PlacedObject(obj_id, plate @ resting, material)
        yield simulator.frame_of(base + i, [placed], environment=base), angle


def write_capture_bag(simulator: Simulator, obj_id: int, out: str | Path, *,
                      part: str | None = None,
                      params: CaptureSessionParams = CaptureSessionParams(), seed: int = 0,
                      fps: float = 15.0, with_background: bool = False,
                      progress: bool = False) -> CaptureLabel:
    """Render one part's session into a new capture bag folder ``out`` (mcap + capture.yaml;
    ``with_background``: also ``out/background``, a bag of the empty table, in the label).

    Returns:
        the label written.
    """
    bag_params = BagParams(fps=fps, with_clouds=False, with_ground_truth=False)
    angles: list[float] = []

    def frames() -> Iterator[SimulatedFrame]:
        session = capture_session(simulator, obj_id, params=params, seed=seed)
        if progress:
            from tqdm import tqdm

            session = tqdm(session, total=params.frames, desc=f'capture obj_{obj_id:02d}',
                           unit='frame')
        for frame, angle in session:
            angles.append(angle)
            yield frame

    write_bag(frames(), out, params=bag_params)
    background = ''
    if with_background:   # the session's empty table, before the part was put down
        empty = SimulatedFrame(0, 0, [], simulator.empty_table(seed * 100_000))
        write_bag([empty], Path(out) / BACKGROUND_BAG, params=bag_params)
        background = BACKGROUND_BAG
    label = CaptureLabel(
        part=part or f'obj_{obj_id:02d}', obj_id=obj_id, cameras=list(simulator.rig.cameras),
        frames=[{'stamp_ns': bag_params.start_ns + round(i * 1e9 / fps), 'turntable_deg': a}
                for i, a in enumerate(angles)], background=background)
    label.write(out)
    return label
