"""The rig of a parameter YAML, for the commands (simulate, evaluate --bag)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from tlessbot_ros.core.common import CameraIntrinsics, CameraMount, Rig, rig_from_params
from tlessbot_ros.errors import TlessbotError
from tlessbot_ros.io.config import default_config_path, load_ros_params


def load_rig(config: Path | None = None, *, width: int | None = None,
             height: int | None = None) -> Rig:
    """The rig of a parameter YAML (``config/cell.yaml`` when None), with intrinsics rescaled
    to ``width`` x ``height`` (pixels; give both to change the aspect ratio)."""
    path = config or default_config_path()
    try:
        rig = rig_from_params(load_ros_params(path))
    except ValueError as error:
        raise TlessbotError(f'{path}: {error}') from None
    if width is None and height is None:
        return rig
    cameras = {}
    for name, cam in rig.cameras.items():
        w = width or cam.intrinsics.width
        h = height or cam.intrinsics.height
        sx, sy = w / cam.intrinsics.width, h / cam.intrinsics.height
        if abs(sx - sy) > 1e-6 and (width is None or height is None):
            raise TlessbotError('give both --width and --height when changing the aspect ratio')
        K = np.array(cam.intrinsics.K, dtype=np.float64)
        s = min(sx, sy)  # keep square pixels; a wider/taller image adds field of view
        K[0, 0] *= s
        K[1, 1] *= s
        K[0, 2] = (K[0, 2] + 0.5) * s - 0.5 + (w - cam.intrinsics.width * s) / 2
        K[1, 2] = (K[1, 2] + 0.5) * s - 0.5 + (h - cam.intrinsics.height * s) / 2
        cameras[name] = CameraMount(name, CameraIntrinsics(width=w, height=h, K=K),
                                    cam.T_world_camera)
    return Rig(cameras=cameras, world_frame=rig.world_frame)
