import numpy as np
import pytest

from tlessbot_ros.core.common import (
    CAMERA_NAMES,
    check_camera_roles,
    default_rig,
    look_at,
    look_at_params,
    project_points,
    rig_from_params,
    rotation_about_axis,
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


def test_look_at_params_round_trip_through_rig_parameters():
    # A rig with rolled, tilted cameras (as a calibration finds them) survives the YAML form.
    rig = default_rig()
    for name, angle in (('top', 0.2), ('side', -0.15)):
        T = rig[name].T_world_camera
        T[:3, :3] = rotation_about_axis([0.3, -0.5, 0.8], angle) @ T[:3, :3]
        T[:3, 3] += [0.04, -0.03, 0.02]
    flat = {'rig.cameras': ['top', 'side']}
    for name, cam in rig.cameras.items():
        K = cam.intrinsics.K
        flat.update({f'rig.{name}.width': cam.intrinsics.width,
                     f'rig.{name}.height': cam.intrinsics.height,
                     f'rig.{name}.fx': K[0, 0], f'rig.{name}.fy': K[1, 1],
                     f'rig.{name}.cx': K[0, 2], f'rig.{name}.cy': K[1, 2]})
        for key, value in zip(('position_m', 'look_at_m', 'up'),
                              look_at_params(cam.T_world_camera)):
            flat[f'rig.{name}.{key}'] = [round(float(v), 6) for v in value]
    back = rig_from_params(flat)
    for name in ('top', 'side'):
        np.testing.assert_allclose(back[name].T_world_camera, rig[name].T_world_camera,
                                   atol=5e-6)
        np.testing.assert_allclose(back[name].intrinsics.K, rig[name].intrinsics.K)
    # The optical axis of the default top camera meets the table at the origin.
    position, target, up = look_at_params(
        look_at([0.0, 0.0, 1.1], [0.0, 0.0, 0.0], [0.0, 1.0, 0.0]))
    np.testing.assert_allclose([position, target, up],
                               [[0.0, 0.0, 1.1], [0.0, 0.0, 0.0], [0.0, 1.0, 0.0]], atol=1e-12)
    # A camera looking above the horizon gets a point 1 m along its axis.
    position, target, _ = look_at_params(
        look_at([0.0, 0.0, 0.5], [0.0, 1.0, 0.6], [0.0, 0.0, 1.0]))
    assert np.linalg.norm(target - position) == pytest.approx(1.0)
