"""config/cell.yaml loads into every perception node; ``rig.cameras`` must name the two roles the
pipeline fuses, or one camera; a stage parameter out of range stops a node at start-up with one
clear error."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

pytestmark = pytest.mark.ros

CELL_YAML = Path(__file__).resolve().parents[2] / 'config' / 'cell.yaml'


@pytest.fixture
def ros():
    import rclpy

    rclpy.init()
    yield
    rclpy.try_shutdown()


def _cell_args() -> list[str]:
    return ['--ros-args', '--params-file', str(CELL_YAML)]


def test_cell_yaml_loads_into_every_perception_node(ros):
    from rclpy.parameter import Parameter

    from tlessbot_ros.core.common import CAMERA_NAMES
    from tlessbot_ros.nodes.classifier import ClassifierNode
    from tlessbot_ros.nodes.localiser import LocaliserNode
    from tlessbot_ros.nodes.pose_estimator import PoseEstimatorNode

    localiser = LocaliserNode(cli_args=_cell_args())
    assert set(localiser.cameras) == set(CAMERA_NAMES)
    assert localiser.sync_params.max_rate_hz == 0.0 and localiser.input_qos == 'reliable'
    assert localiser.in_flight.params.max_in_flight == 2
    assert localiser.localise_params.parallel_views is True
    localiser.destroy_node()
    classifier = ClassifierNode(cli_args=_cell_args())
    assert classifier.classify_params.class_candidates == 3
    assert classifier.get_parameter('top_view_verify_below_margin').value == 0.25
    classifier.destroy_node()
    # workers.count (1 in cell.yaml) is overridden: the parameter file still has to load
    pose = PoseEstimatorNode(cli_args=_cell_args(),
                             parameter_overrides=[Parameter('workers.count', value=0)])
    assert pose.pipeline.fit_params.verify_accept_fitness == 0.9
    assert pose.get_parameter('lookalike_check').value is True
    assert pose.world_frame == 'world' and pose.workers is None
    pose.destroy_node()


@pytest.mark.parametrize('cameras', [['top', 'left'], ['side', 'side'],
                                     ['top', 'side', 'left']])
def test_a_rig_without_exactly_the_top_and_side_roles_is_rejected(ros, cameras):
    from rclpy.parameter import Parameter

    from tlessbot_ros.errors import CalibrationError
    from tlessbot_ros.nodes.localiser import LocaliserNode

    with pytest.raises(CalibrationError) as error:
        LocaliserNode(parameter_overrides=[Parameter('rig.cameras', value=cameras)])
    message = str(error.value)
    assert str(cameras) in message and "['top', 'side']" in message


def test_cameras_in_either_order_are_accepted(ros):
    from rclpy.parameter import Parameter

    from tlessbot_ros.nodes.localiser import LocaliserNode

    node = LocaliserNode(parameter_overrides=[Parameter('rig.cameras', value=['side', 'top'])])
    assert node.cameras == ('side', 'top') and set(node.extrinsics) == {'top', 'side'}
    node.destroy_node()


@pytest.mark.parametrize('camera', ['side', 'top', 'front'])
def test_a_rig_of_one_camera_of_any_name_is_accepted(ros, camera):
    from rclpy.parameter import Parameter

    from tlessbot_ros.core.common import default_rig
    from tlessbot_ros.nodes.localiser import LocaliserNode

    node = LocaliserNode(parameter_overrides=[Parameter('rig.cameras', value=[camera])])
    assert node.cameras == (camera,) and node.main_camera == camera
    role = 'top' if camera == 'top' else 'side'   # the default pose of a camera of any name
    np.testing.assert_allclose(node.extrinsics[camera], default_rig()[role].T_world_camera,
                               atol=1e-9)
    node.destroy_node()


def test_a_stage_parameter_out_of_range_is_one_clear_error(ros):
    from rclpy.parameter import Parameter

    from tlessbot_ros.errors import TlessbotError
    from tlessbot_ros.nodes.classifier import ClassifierNode

    with pytest.raises(TlessbotError, match=r'class_candidates must be 1\.\.4.*got 5'):
        ClassifierNode(parameter_overrides=[Parameter('class_candidates', value=5)])


def test_the_localiser_warms_up_at_the_size_of_its_empty_table_image(ros, tmp_path):
    """An empty-table image of another size than 640x480 (a 1280x720 camera, say): the warm-up
    frame takes its size, so the node still gets ready."""
    import cv2
    import numpy as np
    from rclpy.parameter import Parameter

    from tlessbot_ros.nodes.localiser import LocaliserNode

    path = tmp_path / 'empty_side.png'
    cv2.imwrite(str(path), np.full((240, 320, 3), 190, np.uint8))
    node = LocaliserNode(parameter_overrides=[Parameter('background.side', value=str(path))])
    try:
        assert node.wait_ready(120.0), node.last_error
    finally:
        node.destroy_node()


def test_the_nodes_declare_the_fit_ranking_parameters_off_by_default(ros):
    """Recognition by fit (core/by_fit.py): node parameters from the core dataclasses, off by
    default; a bad value is refused live."""
    from rclpy.parameter import Parameter

    from tlessbot_ros.core.params import ClassifyParams, FitParams
    from tlessbot_ros.nodes.classifier import ClassifierNode
    from tlessbot_ros.nodes.pose_estimator import PoseEstimatorNode

    classifier = ClassifierNode()
    try:
        assert classifier.classify_params == ClassifyParams()
        assert classifier.candidates == ClassifyParams().class_candidates   # 16UC3 as before
        for name in ('fit_rank_below_margin', 'fit_rank_max_candidates'):
            assert classifier.get_parameter(name).value == getattr(ClassifyParams(), name)
            text = classifier.describe_parameters([name])[0].description
            assert 'fit' in text and len(text) < 250
        refused = classifier.set_parameters([Parameter('fit_rank_below_margin', value=-1.0)])
        assert not refused[0].successful and 'fit_rank_below_margin' in refused[0].reason
    finally:
        classifier.destroy_node()
    # with fit ranking on, unsure parts send up to 4 candidates (16UC4), the most an image holds
    unsure = ClassifierNode(parameter_overrides=[Parameter('fit_rank_below_margin', value=1.0)])
    try:
        assert unsure.candidates == 4 and unsure.classify_params.fit_rank_below_margin == 1.0
    finally:
        unsure.destroy_node()
    pose = PoseEstimatorNode(parameter_overrides=[
        Parameter('workers.count', value=0), Parameter('fit_rank_min_fitness', value=0.4)])
    try:
        assert pose.get_parameter('fit_rank_coverage_weight').value == \
            FitParams().fit_rank_coverage_weight
        assert pose.pipeline.fit_params.fit_rank_min_fitness == 0.4
    finally:
        pose.destroy_node()


def test_a_broken_parts_folder_stops_the_stage_nodes_at_start(ros, tmp_path):
    from rclpy.parameter import Parameter

    from tlessbot_ros.io.parts import PartsFolderError
    from tlessbot_ros.nodes.classifier import ClassifierNode
    from tlessbot_ros.nodes.localiser import LocaliserNode
    from tlessbot_ros.nodes.pose_estimator import PoseEstimatorNode

    (tmp_path / 'manifest.json').write_text('{}')
    for node_class in (LocaliserNode, ClassifierNode, PoseEstimatorNode):
        with pytest.raises(PartsFolderError, match='has no classifier.npz: rebuild it'):
            node_class(parameter_overrides=[Parameter('parts_path', value=str(tmp_path))])
