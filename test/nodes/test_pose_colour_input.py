"""The pose estimator reads the colour images only with ``colour_input`` (flat and
near-symmetric parts' checks); a parts folder turns it on by default."""
from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

pytestmark = pytest.mark.ros


@pytest.fixture(scope='module')
def templates_file(part21_seen_from_the_side, tmp_path_factory):
    path = tmp_path_factory.mktemp('colour') / 'templates.npz'
    part21_seen_from_the_side[0].save(path)
    return path


def _messages(with_colour: bool) -> dict:
    from tlessbot_ros.conversions import array_to_image, intrinsics_to_camera_info
    from tlessbot_ros.core.common import default_rig

    intrinsics = default_rig()['side'].intrinsics
    h, w = intrinsics.height, intrinsics.width
    msgs = {'info': intrinsics_to_camera_info(intrinsics, frame_id='side_color_optical_frame'),
            'depth': array_to_image(np.full((h, w), 600, np.uint16), '16UC1'),
            'classes': array_to_image(np.zeros((h, w), np.uint16), '16UC1')}
    if with_colour:
        msgs['color'] = array_to_image(np.full((h, w, 3), 90, np.uint8), 'rgb8')
    return msgs


@pytest.mark.parametrize('colour_input', [False, True])
def test_colour_reaches_the_pipeline_only_when_asked_for(templates_file, colour_input):
    import rclpy
    from rclpy.parameter import Parameter

    from tlessbot_ros.nodes.pose_estimator import PoseEstimatorNode

    rclpy.init()
    try:
        node = PoseEstimatorNode(parameter_overrides=[
            Parameter('templates_path', value=str(templates_file)),
            Parameter('colour_input', value=colour_input)])
        try:
            assert node.describe_parameter('colour_input').read_only
            view, _, _ = node._view_input('side', _messages(colour_input))
            assert (view.rgb is not None) == colour_input
            if colour_input:
                assert view.rgb.shape == view.depth_m.shape + (3,)
        finally:
            node.destroy_node()
    finally:
        rclpy.try_shutdown()


def _parts_folder(tmp_path, templates_file):
    from tlessbot_ros.core.common import default_rig
    from tlessbot_ros.io.parts import FORMAT, REQUIRED, TEMPLATES, rig_summary

    (tmp_path / 'models').mkdir()
    for name in REQUIRED:
        (tmp_path / name).write_text('{}')
    shutil.copy(templates_file, tmp_path / TEMPLATES)
    (tmp_path / 'manifest.json').write_text(json.dumps({
        'format': FORMAT, 'rig': rig_summary(default_rig()),
        'parts': [{'id': 21, 'name': 'bracket'}]}))
    return tmp_path


@pytest.mark.parametrize('with_parts', [False, True])
def test_a_parts_folder_reads_the_colour_by_default(templates_file, tmp_path, with_parts):
    """Own parts are scored by `tlessbot evaluate` with their colour checks; the graph runs
    them the same way without a setting, and the packaged set keeps its depth-only inputs."""
    import rclpy
    from rclpy.parameter import Parameter

    from tlessbot_ros.nodes.pose_estimator import PoseEstimatorNode

    overrides = ([Parameter('parts_path', value=str(_parts_folder(tmp_path, templates_file)))]
                 if with_parts else [Parameter('templates_path', value=str(templates_file))])
    rclpy.init()
    try:
        node = PoseEstimatorNode(parameter_overrides=overrides)
        try:
            assert node.get_parameter('colour_input').value is with_parts
            view, _, _ = node._view_input('side', _messages(with_parts))
            assert (view.rgb is not None) == with_parts
        finally:
            node.destroy_node()
    finally:
        rclpy.try_shutdown()
