"""Parameters change while a node runs (in-process; the real ``ros2 param set`` against node
processes is test/e2e/test_live_parameters_ros2.py).

A change is validated by the core dataclass (refused with its message, the old value kept) and
applied between frames, never during one; structural parameters are read-only; every
parameter a node declares is one or the other, and its description says which.
"""
from __future__ import annotations

import threading
import time

import numpy as np
import pytest

pytestmark = pytest.mark.ros


@pytest.fixture
def ros():
    import rclpy

    rclpy.init()
    yield
    rclpy.try_shutdown()


def _set(node, name, value):
    from rclpy.parameter import Parameter

    [result] = node.set_parameters([Parameter(name, value=value)])
    return result


def _wait(condition, timeout_s=30.0) -> bool:
    deadline = time.monotonic() + timeout_s
    while not condition():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.01)
    return True


def _probe_class():
    """A StageNode with a live ClassifyParams group whose frames record the settings they see
    at their start and at their end; a frame waits for ``release`` in between."""
    from tlessbot_ros.core.params import ClassifyParams
    from tlessbot_ros.nodes.stage import StageNode

    class Probe(StageNode):
        def __init__(self, **kwargs):
            super().__init__('live_probe', **kwargs)
            self.settings = self.parameters.dataclass(
                ClassifyParams(), apply=lambda params: setattr(self, 'settings', params))
            self.release = threading.Event()
            self.seen = []   # (candidates at the start, at the end, top camera position)

        def process(self, views):
            start = self.settings.class_candidates
            self.release.wait(timeout=30.0)
            self.seen.append((start, self.settings.class_candidates,
                              tuple(self.extrinsics['top'][:3, 3])))

    return Probe


def test_a_change_waits_for_the_frame_in_progress_and_applies_to_the_next(ros):
    node = _probe_class()()
    try:
        node._on_views({})
        assert _wait(lambda: node._busy)                 # frame 0 started with 3 candidates
        assert _set(node, 'class_candidates', 1).successful
        assert _set(node, 'rig.top.position_m', [0.0, 0.1, 1.0]).successful
        assert node.get_parameter('class_candidates').value == 1
        node.release.set()
        assert node.wait_idle()
        assert node.seen == [(3, 3, (0.0, 0.0, 1.1))]    # nothing changed during the frame
        node._on_views({})
        assert node.wait_idle()
        assert node.seen[-1] == (1, 1, (0.0, 0.1, 1.0))  # both changes, from the next frame
        assert node.parameters.changes == 2
        assert node.parameters.last_change == 'rig.top.position_m=[0.0, 0.1, 1.0]'
    finally:
        node.release.set()
        node.destroy_node()


def test_an_invalid_value_is_refused_with_the_dataclass_reason_and_the_old_one_kept(ros):
    from tlessbot_ros.core.params import ClassifyParams

    node = _probe_class()()
    try:
        with pytest.raises(ValueError) as expected:
            ClassifyParams(class_candidates=9)
        result = _set(node, 'class_candidates', 9)
        assert not result.successful and result.reason == str(expected.value)
        assert node.get_parameter('class_candidates').value == 3
        assert not node.parameters.pending and node.parameters.changes == 0
        # a camera on the point it looks at has no viewing direction
        result = _set(node, 'rig.top.position_m', [0.0, 0.0, 0.0])
        assert not result.successful and 'coincide' in result.reason
        assert list(node.get_parameter('rig.top.position_m').value) == [0.0, 0.0, 1.1]
        # rcl checks the type first, as at start-up: a double list takes no integers
        result = _set(node, 'rig.top.position_m', [0, 1, 1])
        assert not result.successful and 'Wrong parameter type' in result.reason
    finally:
        node.destroy_node()


def test_fields_checked_together_can_be_changed_together(ros):
    from rclpy.parameter import Parameter

    from tlessbot_ros.nodes.localiser import LocaliserNode

    node = LocaliserNode()
    try:
        result = _set(node, 'segmentation.cutoff_sigma', 10.0)   # above sure_sigma (9)
        assert not result.successful
        assert result.reason.startswith('segmentation.cutoff_sigma: need 0 < cutoff_sigma')
        assert node.set_parameters_atomically([
            Parameter('segmentation.cutoff_sigma', value=10.0),
            Parameter('segmentation.sure_sigma', value=12.0)]).successful
        node.parameters.apply_pending()
        assert (node.segmentation.cutoff_sigma, node.segmentation.sure_sigma) == (10.0, 12.0)
    finally:
        node.destroy_node()


@pytest.mark.parametrize('name, value', [('rig.cameras', ['side', 'top']),
                                         ('input_qos', 'reliable'), ('input_depth', 5),
                                         ('sync.worker_thread', False),
                                         ('sync.executor', 'single_threaded')])
def test_structural_parameters_are_read_only(ros, name, value):
    node = _probe_class()()
    try:
        before = node.get_parameter(name).value
        result = _set(node, name, value)
        assert not result.successful and 'read-only' in result.reason
        assert node.describe_parameter(name).read_only
        assert '(read-only' in node.describe_parameter(name).description
        assert node.get_parameter(name).value == before
    finally:
        node.destroy_node()


def test_the_entrance_keeps_the_single_threaded_executor_and_the_later_stages_use_events(ros):
    """The localiser pauses its camera inputs in DDS, which only the SingleThreadedExecutor
    allows; the classifier and the pose estimator spin the EventsExecutor; run_node spins each
    with its own (``executor_kind``), and a cell YAML may choose either."""
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.parameter import Parameter

    from tlessbot_ros.nodes.classifier import ClassifierNode
    from tlessbot_ros.nodes.common import make_executor
    from tlessbot_ros.nodes.localiser import LocaliserNode

    nodes = [LocaliserNode(), ClassifierNode(),
             LocaliserNode(parameter_overrides=[Parameter('sync.executor', value='events')])]
    try:
        assert [node.executor_kind for node in nodes] == ['single_threaded', 'events', 'events']
        assert isinstance(make_executor(nodes[0].executor_kind, None), SingleThreadedExecutor)
        assert not isinstance(make_executor(nodes[1].executor_kind, None),
                              SingleThreadedExecutor)
        with pytest.raises(ValueError, match="one of \\['events', 'single_threaded', "
                                             "'multi_threaded'\\], got 'static'"):
            make_executor('static', None)
    finally:
        for node in nodes:
            node.destroy_node()


def test_sync_changes_apply_at_once_and_restart_the_pairing(ros):
    from tlessbot_ros.conversions.image_cdr import image_to_cdr
    from tlessbot_ros.nodes.stage import camera_inputs

    node = _probe_class()()
    try:
        node.setup_inputs(camera_inputs(['color']))
        inputs = node._inputs
        handler = inputs._handler('top', 'color', object)
        handler(image_to_cdr(np.zeros((2, 2), np.uint16), '16UC1', stamp_ns=10**9))
        assert inputs.waiting == 1 and inputs.dropped == 0   # the top set waits for the side
        assert _set(node, 'sync.max_rate_hz', 4.0).successful
        assert node.sync_params.max_rate_hz == 4.0 and inputs.waiting == 1   # same pairing
        assert _set(node, 'sync.max_age_s', 0.02).successful
        assert inputs._across.slop_ns == 20_000_000
        assert inputs.waiting == 0 and inputs.dropped == 1   # what waited is counted as dropped
        result = _set(node, 'sync.queue_size', 0)
        assert not result.successful and 'queue_size' in result.reason
    finally:
        node.destroy_node()


def test_the_localiser_reloads_its_empty_table_image_and_refuses_an_unreadable_one(ros,
                                                                                  tmp_path):
    import cv2

    from tlessbot_ros.nodes.localiser import LocaliserNode

    path = tmp_path / 'empty_top.png'
    cv2.imwrite(str(path), np.full((48, 64, 3), 190, np.uint8))
    node = LocaliserNode()
    try:
        assert 'top' not in node.backgrounds
        result = _set(node, 'background.top', str(tmp_path / 'missing.png'))
        assert not result.successful and 'cannot read background image' in result.reason
        assert _set(node, 'background.top', str(path)).successful
        node.parameters.apply_pending()
        assert node.backgrounds['top'].rgb.shape == (48, 64, 3)
        assert node.backgrounds['top'].scale == 0.5
        # the colour cues of the empty table follow the segmentation's scale
        assert _set(node, 'segmentation.cue_scale', 1.0).successful
        node.parameters.apply_pending()
        assert node.backgrounds['top'].scale == 1.0
        assert _set(node, 'background.top', '').successful
        node.parameters.apply_pending()
        assert 'top' not in node.backgrounds
    finally:
        node.destroy_node()


def test_the_classifier_swaps_its_model_once_the_new_one_is_loaded_and_warm(ros):
    from tlessbot_ros.data import DEFAULT_CLASSIFIER
    from tlessbot_ros.nodes.classifier import ClassifierNode

    node = ClassifierNode()
    try:
        assert node.wait_ready(120.0)
        result = _set(node, 'model_path', '/nonexistent/classifier.npz')
        assert not result.successful and 'does not exist' in result.reason
        old = node.model
        assert _set(node, 'model_path', str(DEFAULT_CLASSIFIER)).successful
        assert _wait(lambda: node.parameters.pending, 120.0)   # loaded and warmed up
        assert node.model is old                               # until the next frame
        node.parameters.apply_pending()
        assert node.model is not old and node.pipeline.classifier is node.model
        assert _set(node, 'class_candidates', 1).successful
        node.parameters.apply_pending()
        assert node.candidates == 1 and node.pipeline.classify_params.class_candidates == 1
    finally:
        node.destroy_node()


def test_the_camera_driver_changes_its_cloud_at_once_but_not_its_stream(ros, monkeypatch):
    from tlessbot_ros.nodes import camera_driver
    from tlessbot_ros.sensors import realsense

    monkeypatch.setattr(realsense, 'connected_serials', lambda: [])
    node = camera_driver.CameraDriverNode()
    try:
        assert _set(node, 'cloud_stride', 4).successful and node.params.cloud_stride == 4
        result = _set(node, 'reconnect_period_s', 0.0)
        assert not result.successful and 'reconnect_period_s must be > 0' in result.reason
        for name, value in (('fps', 15), ('serial_no', '_123'), ('width', 1280)):
            assert 'read-only' in _set(node, name, value).reason
    finally:
        node.destroy_node()


@pytest.fixture(scope='module')
def small_templates(part21_seen_from_the_side, tmp_path_factory):
    path = tmp_path_factory.mktemp('live') / 'templates.npz'
    part21_seen_from_the_side[0].save(path)
    return path


def test_every_parameter_of_every_node_is_live_or_read_only(ros, small_templates, monkeypatch):
    from rclpy.parameter import Parameter

    from tlessbot_ros.nodes.camera_driver import CameraDriverNode
    from tlessbot_ros.nodes.classifier import ClassifierNode
    from tlessbot_ros.nodes.localiser import LocaliserNode
    from tlessbot_ros.nodes.pose_estimator import PoseEstimatorNode
    from tlessbot_ros.sensors import realsense

    monkeypatch.setattr(realsense, 'connected_serials', lambda: [])
    rclpy_own = {'use_sim_time', 'start_type_description_service'}
    for make in (LocaliserNode, ClassifierNode, CameraDriverNode,
                 lambda: PoseEstimatorNode(parameter_overrides=[
                     Parameter('templates_path', value=str(small_templates))])):
        node = make()
        try:
            names = set(node._parameters) - rclpy_own
            assert len(names) > 5
            for name in sorted(names):
                described = node.describe_parameter(name)
                assert described.read_only != node.parameters.is_live(name), name
                assert ('(read-only' if described.read_only else '(live') in \
                    described.description, name
        finally:
            node.destroy_node()


def test_the_pose_estimator_changes_its_fit_and_its_workers(ros, small_templates):
    from rclpy.parameter import Parameter

    from tlessbot_ros.nodes.pose_estimator import PoseEstimatorNode

    node = PoseEstimatorNode(parameter_overrides=[
        Parameter('templates_path', value=str(small_templates)),
        Parameter('workers.count', value=0)])
    try:
        assert node.wait_ready(300.0)
        database = node.pipeline.pose_estimator.database
        assert _set(node, 'min_fitness', 2.0).successful
        assert _set(node, 'pose.cloud.sor_neighbors', 20).successful
        assert not _set(node, 'pose.cloud.sor_neighbors', 0).successful
        assert _set(node, 'lookalike_check', False).successful
        assert _set(node, 'output_frame', 'world').successful
        result = _set(node, 'output_frame', 'map')
        assert not result.successful and "output_frame must be 'camera' or 'world'" in \
            result.reason
        assert _set(node, 'workers.count', 1).successful
        assert 'read-only' in _set(node, 'templates_path', 'other.npz').reason
        assert node.min_fitness == 0.3 and node.workers is None   # until the next frame
        node.parameters.apply_pending()
        assert (node.min_fitness, node.output_frame) == (2.0, 'world')
        assert node.pipeline.pose_estimator.params.cloud.sor_neighbors == 20
        assert node.pipeline.pose_estimator.database is database   # caches kept
        assert node.pipeline.lookalike is None
        assert node.workers is not None and len(node.workers._workers) == 1
        assert node.workers.wait_ready(120.0), list(node.workers.errors)
        worker = node.workers._workers[0]
        assert _set(node, 'workers.count', 0).successful
        node.parameters.apply_pending()
        assert node.workers._workers == []
        assert _wait(lambda: worker.process.poll() is not None)   # stopped, not left behind
    finally:
        node.destroy_node()
