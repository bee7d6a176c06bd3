"""The two-camera cell: intrinsics and extrinsics of ``top`` and ``side``.

The world frame is the table plane at z = 0 with z up (REP-103). Each camera is described in its
colour optical frame ``<name>_color_optical_frame``; depth is aligned to colour. Defaults follow
the paper's §4: top camera 1.10 m above the table looking straight down; side camera 0.60 m high,
its optical axis at 70° to the table plane, both aimed at the centre of the work area.
"""
from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, cast

import numpy as np

from tlessbot_ros.core.common.geometry import CameraIntrinsics, invert_transform, look_at
from tlessbot_ros.errors import CalibrationError

# The cameras the two-view pipeline knows, by role: ``top`` looks down on the table, ``side``
# sees the parts from the side. A rig (config/cell.yaml ``rig.cameras``) names these.
TOP, SIDE = 'top', 'side'
CAMERA_NAMES = (TOP, SIDE)



def check_camera_roles(names: Sequence[str]) -> tuple[str, ...]:
    """The camera names of a rig (``rig.cameras``) if the pipeline can run on them: the two
    roles it fuses, :data:`CAMERA_NAMES` in any order, or one camera of any name (a single
    view: no fusion, every part read in that camera).

    Raises:
        CalibrationError: other names, a missing role or a repeated one; the message names
            what was found and what is supported.
    """
    names = tuple(str(name) for name in names)
    if len(names) == 1 and names[0]:
        return names
    if len(names) != len(CAMERA_NAMES) or set(names) != set(CAMERA_NAMES):
        raise CalibrationError(
            f'rig.cameras is {list(names)}, but the pipeline fuses exactly two cameras named '
            f'{list(CAMERA_NAMES)} ({TOP!r} looks down on the table, {SIDE!r} from the side), '
            'or runs on one camera of any name; name the cameras of config/cell.yaml so')
    return names


# D415 colour stream at 640x480 (4:3 crop of the sensor): fx ~ fy ~ 615 px.
D415_FOCAL_PX_AT_640 = 615.0


@dataclass(frozen=True)
class CameraMount:
    """One camera of the rig: ``T_world_camera`` maps optical-frame points into the world."""

    name: str
    intrinsics: CameraIntrinsics
    T_world_camera: np.ndarray

    @property
    def optical_frame(self) -> str:
        return f'{self.name}_color_optical_frame'

    @property
    def T_camera_world(self) -> np.ndarray:
        return invert_transform(self.T_world_camera)


@dataclass(frozen=True)
class Rig:
    """The cameras of the cell, keyed by name ('top', 'side')."""

    cameras: dict[str, CameraMount] = field(default_factory=dict)
    world_frame: str = 'world'

    def __getitem__(self, name: str) -> CameraMount:
        try:
            return self.cameras[name]
        except KeyError:
            raise KeyError(f'rig has no camera {name!r}; it has {sorted(self.cameras)}') from None

    def T_a_b(self, camera_a: str, camera_b: str) -> np.ndarray:
        """Transform from camera ``b``'s optical frame into camera ``a``'s."""
        return cast(np.ndarray, self[camera_a].T_camera_world @ self[camera_b].T_world_camera)


def d415_intrinsics(width: int = 640, height: int = 480) -> CameraIntrinsics:
    """D415-like colour intrinsics; 1280x720 scales the focal length by 1.5 (same vertical FOV
    crop as the real sensor's 16:9 modes)."""
    focal = D415_FOCAL_PX_AT_640 * (width / 640.0 if width * 3 == height * 4 else height / 480.0)
    K = np.array([[focal, 0.0, (width - 1) / 2.0], [0.0, focal, (height - 1) / 2.0],
                  [0.0, 0.0, 1.0]])
    return CameraIntrinsics(width=width, height=height, K=K)


def side_camera_position(height_m: float, tilt_deg: float,
                         target: np.ndarray | None = None) -> np.ndarray:
    """Position of a camera ``height_m`` above the table whose optical axis meets the table plane
    at ``tilt_deg`` when aimed at ``target``; it stands on the -y side of the target."""
    target = np.zeros(3) if target is None else np.asarray(target, dtype=np.float64)
    if not 0.0 < tilt_deg <= 90.0:
        raise ValueError(f'tilt must be in (0, 90] degrees, got {tilt_deg}')
    back = (height_m - target[2]) / np.tan(np.radians(tilt_deg))
    return np.array([target[0], target[1] - back, height_m])


def default_rig(width: int = 640, height: int = 480) -> Rig:
    """The paper's cell: top at 1.10 m looking down, side at 0.60 m tilted 70°."""
    intrinsics = d415_intrinsics(width, height)
    target = np.zeros(3)
    top = look_at([0.0, 0.0, 1.10], target, up=[0.0, 1.0, 0.0])
    side = look_at(side_camera_position(0.60, 70.0), target, up=[0.0, 0.0, 1.0])
    return Rig(cameras={TOP: CameraMount(TOP, intrinsics, top),
                        SIDE: CameraMount(SIDE, intrinsics, side)})


def look_at_params(T_world_camera: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The ``position_m``, ``look_at_m`` and ``up`` of config/cell.yaml that give a camera pose
    (:func:`~tlessbot_ros.core.common.geometry.look_at` gives it back exactly).

    Args:
        T_world_camera: (4, 4) optical-frame camera pose in the world (z up, z = 0 the table).

    Returns:
        (3,) position: the camera centre; (3,) look_at: where the optical axis meets the table
        (a point 1 m along it when it does not look down); (3,) up: the world direction at the
        top of the image (minus the camera's y axis). Metres, float64.
    """
    T = np.asarray(T_world_camera, np.float64)
    position, axis = T[:3, 3], T[:3, 2]
    distance = -position[2] / axis[2] if axis[2] < -1e-3 and position[2] > 0 else 1.0
    return position.copy(), position + distance * axis, -T[:3, 1]


def rig_from_params(params: Mapping[str, Any], *, prefix: str = 'rig') -> Rig:
    """Rig from flat ROS parameters (as read from config/cell.yaml).

    Expected keys per camera NAME listed in ``<prefix>.cameras``: ``<prefix>.NAME.position_m``,
    ``.look_at_m``, ``.up``, ``.width``, ``.height``, ``.fx``, ``.fy``, ``.cx``, ``.cy``.
    """
    names = params.get(f'{prefix}.cameras')
    if not names:
        raise ValueError(f"parameters have no '{prefix}.cameras' list")
    cameras = {}
    for name in names:
        def get(key: str, name: str = name) -> Any:
            full = f'{prefix}.{name}.{key}'
            if full not in params:
                raise ValueError(f'missing rig parameter {full!r}')
            return params[full]

        K = np.array([[get('fx'), 0.0, get('cx')], [0.0, get('fy'), get('cy')], [0, 0, 1.0]])
        intrinsics = CameraIntrinsics(width=int(get('width')), height=int(get('height')), K=K)
        T = look_at(np.asarray(get('position_m'), float), np.asarray(get('look_at_m'), float),
                    np.asarray(get('up'), float))
        cameras[name] = CameraMount(name, intrinsics, T)
    return Rig(cameras=cameras, world_frame=str(params.get('world_frame', 'world')))
