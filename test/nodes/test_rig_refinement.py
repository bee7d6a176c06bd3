"""The localiser checks its configured rig against what the cameras see (rig_refinement.*):
with a wrong rig it warns on /diagnostics and fuses with the rig the scene shows; with the
right one it keeps it (in-process, on the demo bag, recorded with config/cell.yaml's rig)."""
from __future__ import annotations

import time

import numpy as np
import pytest

pytestmark = pytest.mark.ros

BAG = 'bags/demo'


@pytest.fixture
def ros():
    import rclpy

    rclpy.init()
    yield
    rclpy.try_shutdown()


@pytest.fixture(scope='module')
def frames():
    """The demo bag's frames as the localiser's ``process`` takes them."""
    from tlessbot_ros.conversions.topics import COLOR, DEPTH, DEPTH_INFO, camera_topic
    from tlessbot_ros.io.bags import read_bag
    from tlessbot_ros.io.config import package_path
    from tlessbot_ros.nodes.common import message_class
    from tlessbot_ros.nodes.inputs import RawMessage

    inputs = {'color': COLOR, 'depth': DEPTH, 'info': DEPTH_INFO}
    topics = {camera_topic(c, t): (c, k) for k, t in inputs.items() for c in ('top', 'side')}
    by_stamp: dict[int, dict] = {}
    for m in read_bag(package_path(BAG), list(topics)):
        camera, key = topics[m.topic]
        msg = RawMessage(message_class(m.msgtype), m.raw).deserialise()
        stamp = msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec
        by_stamp.setdefault(stamp, {}).setdefault(camera, {})[key] = msg
    return [by_stamp[s] for s in sorted(by_stamp)]


def _moved_rig_overrides():
    """Parameters of config/cell.yaml's rig with the side camera turned 10 deg about the
    vertical and moved 3 cm, and the top one tilted 2 deg and raised 1 cm."""
    from rclpy.parameter import Parameter

    from tlessbot_ros.core.common import look_at_params, rotation_about_axis
    from tlessbot_ros.tools.support.rig import load_rig

    rig = load_rig()
    overrides = []
    for name, axis, degrees, shift in (('side', [0, 0, 1], 10.0, [0.03, 0.0, 0.0]),
                                       ('top', [1, 0, 0], 2.0, [0.0, 0.0, 0.01])):
        T = rig[name].T_world_camera.copy()
        T[:3, :3] = rotation_about_axis(axis, np.radians(degrees)) @ T[:3, :3]
        T[:3, 3] += shift
        for key, value in zip(('position_m', 'look_at_m', 'up'), look_at_params(T)):
            overrides.append(Parameter(f'rig.{name}.{key}', value=[float(v) for v in value]))
    return overrides


def _run(node, frames):
    for views in frames:
        node.process(views)


def _diagnostics(node):
    """The localiser's next /diagnostics status (level, message, values), once it is ready
    (before, it says 'starting')."""
    import rclpy

    from tlessbot_ros.nodes.common import RESULT_QOS, message_class

    assert node.wait_ready()
    got = []
    listener = rclpy.create_node('rig_diagnostics_listener')
    listener.create_subscription(message_class('diagnostic_msgs/msg/DiagnosticArray'),
                                 '/diagnostics', got.append, RESULT_QOS)
    executor = rclpy.executors.SingleThreadedExecutor()
    executor.add_node(listener)
    try:
        deadline = time.monotonic() + 30.0
        while not got and time.monotonic() < deadline:
            node._publish_diagnostics()
            executor.spin_once(timeout_sec=0.2)
    finally:
        executor.remove_node(listener)
        listener.destroy_node()
    assert got, 'no /diagnostics received'
    status = got[0].status[0]
    return status.level, status.message, {kv.key: kv.value for kv in status.values}


def test_a_wrong_rig_is_reported_and_replaced_by_the_one_the_cameras_show(ros, frames):
    from tlessbot_ros.core.calibrate import rig_errors
    from tlessbot_ros.nodes.diagnostics import WARN
    from tlessbot_ros.nodes.localiser import LocaliserNode
    from tlessbot_ros.tools.support.rig import load_rig

    node = LocaliserNode(parameter_overrides=_moved_rig_overrides())
    try:
        _run(node, frames[:1])
        assert node.refiner.in_use in ('config', 'observed')   # tables seen, parts not trusted
        _run(node, frames[1:])
        refiner = node.refiner
        assert refiner.estimate.confident, refiner.estimate.summary()
        assert refiner.in_use == 'observed'
        errors = rig_errors(load_rig(), refiner.rig)   # the bag's true rig
        assert errors.relative.angle_deg < 0.5 and errors.relative.offset_m < 0.005, errors
        level, message, values = _diagnostics(node)
        assert level == WARN and 'the configured rig differs' in message, message
        assert values['rig_in_use'] == 'observed' and values['rig_state'] == 'confident'
        assert float(values['rig_config_top_side_deg']) > 9.0
    finally:
        node.destroy_node()


def test_a_right_rig_is_kept_and_not_reported(ros, frames):
    from tlessbot_ros.nodes.diagnostics import OK
    from tlessbot_ros.nodes.localiser import LocaliserNode

    node = LocaliserNode()
    try:
        _run(node, frames)
        assert node.refiner.estimate.confident, node.refiner.estimate.summary()
        assert node.refiner.in_use == 'config' and node.refiner.rig is node.refiner.prior
        level, message, values = _diagnostics(node)
        assert level == OK, message
        assert float(values['rig_config_top_side_deg']) < 0.5
    finally:
        node.destroy_node()


def test_refinement_none_uses_the_configured_rig_unchecked(ros, frames):
    from rclpy.parameter import Parameter

    from tlessbot_ros.nodes.diagnostics import OK
    from tlessbot_ros.nodes.localiser import LocaliserNode

    node = LocaliserNode(parameter_overrides=[
        *_moved_rig_overrides(), Parameter('rig_refinement.mode', value='none')])
    try:
        _run(node, frames[:2])
        assert node.refiner is None
        level, _, values = _diagnostics(node)
        assert level == OK and values['rig_refinement'] == 'none'
        assert not any(key.startswith('rig_config') for key in values)
    finally:
        node.destroy_node()


def test_the_later_stages_follow_the_rig_the_localiser_fuses_with(ros, frames):
    import rclpy

    from tlessbot_ros.nodes.localiser import LocaliserNode
    from tlessbot_ros.nodes.stage import StageNode, follow_observed_rig

    class Follower(StageNode):   # a later stage: classifier and pose estimator do the same
        def __init__(self, **kwargs):
            super().__init__('rig_follower', **kwargs)
            follow_observed_rig(self)

    follower = Follower(parameter_overrides=_moved_rig_overrides())
    node = LocaliserNode(parameter_overrides=_moved_rig_overrides())
    executor = rclpy.executors.SingleThreadedExecutor()
    executor.add_node(follower)
    try:
        configured = follower.camera_pose('side').copy()
        _run(node, frames)
        assert node.refiner.in_use == 'observed'
        deadline = time.monotonic() + 30.0
        while follower.observed_rig is None and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.1)
        for camera in ('top', 'side'):
            np.testing.assert_allclose(follower.camera_pose(camera),
                                       node.refiner.rig[camera].T_world_camera, atol=1e-9)
        assert not np.allclose(follower.camera_pose('side'), configured, atol=1e-3)
    finally:
        executor.remove_node(follower)
        follower.destroy_node()
        node.destroy_node()
