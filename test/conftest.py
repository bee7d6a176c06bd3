"""Test harness: per-run DDS isolation, markers, shared-data fixtures.

The ROS environment is set here, before any test imports rclpy, so every pytest run gets its own
ROS_DOMAIN_ID and stays on localhost: concurrent runs never hear each other.
"""
from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest

_REPO = Path(__file__).resolve().parents[1]
# Shared test helpers at test/ (ros2_tools.py) import as top-level modules.
sys.path.insert(0, str(Path(__file__).resolve().parent))
SHARED_DATA = Path(os.environ.get('TLESSBOT_SHARED_DATA', _REPO.parent / 'shared' / 'data'))
IN_CI = os.environ.get('CI', '').lower() in ('1', 'true', 'yes')

if 'TLESSBOT_TEST_DOMAIN_ID' in os.environ:
    os.environ['ROS_DOMAIN_ID'] = os.environ['TLESSBOT_TEST_DOMAIN_ID']
else:
    os.environ['ROS_DOMAIN_ID'] = str(1 + os.getpid() % 100)  # Fast DDS: 0..101 are safe
os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
os.environ.setdefault('RMW_IMPLEMENTATION', 'rmw_fastrtps_cpp')


def _rclpy_available() -> bool:
    try:
        import rclpy  # noqa: F401
    except ImportError:
        return False
    return True


def _realsense_connected() -> bool:
    try:
        import pyrealsense2 as rs
    except ImportError:
        return False
    try:
        return rs.context().query_devices().size() > 0
    except RuntimeError:
        return False


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    has_ros = _rclpy_available()
    has_device = None
    for item in items:
        # In CI a missing rclpy must fail the ros tests, never skip them.
        if 'ros' in item.keywords and not has_ros and not IN_CI:
            item.add_marker(pytest.mark.skip(reason='rclpy is not installed'))
        if 'hardware' in item.keywords:
            if has_device is None:
                has_device = _realsense_connected()
            if not has_device:
                item.add_marker(pytest.mark.skip(reason='no RealSense device connected'))


@pytest.fixture(scope='session')
def shared_data() -> Path:
    """The read-only ../shared/data folder (CI has it; a user's clone may not)."""
    if not SHARED_DATA.is_dir():
        if IN_CI:
            pytest.fail(f'shared data missing at {SHARED_DATA}')
        pytest.skip(f'shared data not found at {SHARED_DATA}')
    return SHARED_DATA


@pytest.fixture(scope='session')
def tless_models_dir(shared_data: Path) -> Path:
    return shared_data / 'tless_models_cad_stl'


@pytest.fixture(scope='session')
def part21_seen_from_the_side(tless_models_dir: Path):
    """A template database of objects 5 and 21 (side camera of the default rig) and object 21
    lying on the table, rendered by that camera: (database, depth_m (H, W) float32 with 0 off
    the part, part mask (H, W) bool, T_camera_object (4, 4))."""
    import numpy as np

    from tlessbot_ros.core import pose as tpl
    from tlessbot_ros.core.common import (
        MeshRenderer,
        default_rig,
        make_transform,
        rotation_about_axis,
    )
    from tlessbot_ros.io.models import load_models, stable_poses

    side = default_rig()['side']
    models = load_models(tless_models_dir, ids=[5, 21])
    db = tpl.build_database(
        [(i, m.vertices, m.faces, [(p.T_table_object, p.probability) for p in stable_poses(m)],
          m.diameter_m) for i, m in models.items()],
        intrinsics=side.intrinsics, T_world_camera=side.T_world_camera)
    T_world_object = make_transform(rotation_about_axis([0, 0, 1], np.radians(40)),
                                    [0.01, 0.02, 0]) @ db[21].stable_poses[0]
    renderer = MeshRenderer()
    renderer.add_mesh(models[21].vertices, models[21].faces, T_world_object)
    view = renderer.render(side.intrinsics, side.T_world_camera)
    depth = np.where(view.instance == 0, view.depth_m, 0).astype(np.float32)
    return db, depth, view.instance == 0, side.T_camera_world @ T_world_object
