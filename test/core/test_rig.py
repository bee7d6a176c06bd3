import numpy as np
import pytest

from tlessbot_ros.core.common import (
    CAMERA_NAMES,
    check_camera_roles,
    default_rig,
    project_points,
    rig_from_params,
    side_camera_position,
    transform_points,
)
from tlessbot_ros.errors import CalibrationError
from tlessbot_ros.io.config import default_config_path, load_ros_params


def test_default_rig_matches_the_paper():
    rig = default_rig()
    top, side = rig['top'], rig['side']
    assert top.T_world_camera[2, 3] == pytest.approx(1.10)
    np.testing.assert_allclose(top.T_world_camera[:3, 2], [0, 0, -1], atol=1e-12)
    assert side.T_world_camera[2, 3] == pytest.approx(0.60)
    axis = side.T_world_camera[:3, 2]
    assert np.degrees(np.arcsin(-axis[2])) == pytest.approx(70.0)
    # The table centre projects to both image centres.
    for mount in (top, side):
        uv = project_points(transform_points(mount.T_camera_world, np.zeros((1, 3))),
                            mount.intrinsics.K)
        np.testing.assert_allclose(uv[0], [319.5, 239.5], atol=1e-9)
    assert top.optical_frame == 'top_color_optical_frame'


def test_config_file_gives_the_default_rig():
    params = load_ros_params(default_config_path(), 'pose_estimator')
    rig = rig_from_params(params)
    expected = default_rig()
    for name in ('top', 'side'):
        np.testing.assert_allclose(rig[name].T_world_camera, expected[name].T_world_camera,
                                   atol=1e-5)
        np.testing.assert_allclose(rig[name].intrinsics.K, expected[name].intrinsics.K)
    np.testing.assert_allclose(rig.T_a_b('side', 'top') @ rig.T_a_b('top', 'side'), np.eye(4),
                               atol=1e-12)


def test_bad_tilt_and_missing_params_raise():
    with pytest.raises(ValueError, match='tilt'):
        side_camera_position(0.6, 0.0)
    with pytest.raises(ValueError, match='rig.side.fx'):
        rig_from_params({'rig.cameras': ['side']})


def test_the_rig_of_the_config_file_names_the_two_roles():
    params = load_ros_params(default_config_path(), 'pose_estimator')
    assert check_camera_roles(params['rig.cameras']) == CAMERA_NAMES
    assert check_camera_roles(['side', 'top']) == ('side', 'top')
    with pytest.raises(CalibrationError, match=r"rig.cameras is \['top', 'left'\].*'top', 'side'"):
        check_camera_roles(['top', 'left'])
