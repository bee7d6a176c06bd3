"""Backpressure over DDS: every stage reports what became of each frame on /<node>/frames, and
the localiser admits a frame only while fewer than admission.max_in_flight are unfinished."""
from __future__ import annotations

import threading
import time

import numpy as np
import pytest

pytestmark = pytest.mark.ros


def _views(stamp_ns: int):
    """A one-message two-view frame whose header carries ``stamp_ns``."""
    from tlessbot_ros.conversions.image_cdr import image_to_cdr
    from tlessbot_ros.nodes.common import message_class
    from tlessbot_ros.nodes.inputs import RawMessage

    data = image_to_cdr(np.zeros((2, 2), np.uint16), '16UC1', frame_id='side_color_optical_frame',
                        stamp_ns=stamp_ns)
    return {'side': {'depth': RawMessage(message_class('sensor_msgs/msg/Image'), bytes(data))}}


def _spin_until(executor, condition, timeout_s: float = 30.0) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if condition():
            return True
        executor.spin_once(timeout_sec=0.05)
    return condition()


@pytest.fixture
def ros():
    import rclpy
    from rclpy.executors import SingleThreadedExecutor

    rclpy.init()
    executor = SingleThreadedExecutor()
    nodes = []
    yield executor, nodes
    for node in nodes:
        executor.remove_node(node)
        node.destroy_node()
    rclpy.try_shutdown()


def test_a_stage_reports_done_failed_and_dropped_frames(ros):
    from tlessbot_ros.conversions.outcomes import read_frame_outcome
    from tlessbot_ros.nodes.common import RESULT_QOS, message_class
    from tlessbot_ros.nodes.stage import StageNode

    executor, nodes = ros
    release = threading.Event()

    class Probe(StageNode):
        def __init__(self):
            super().__init__('outcome_probe')

        def process(self, views):
            stamp = views['side']['depth'].header.stamp.sec
            if stamp == 2:
                raise ValueError('a bad frame')
            release.wait(timeout=10.0)

    probe = Probe()
    listener = rclpy_node('outcome_listener')
    heard = []
    listener.create_subscription(message_class('std_msgs/msg/Header'), '/outcome_probe/frames',
                                 lambda msg: heard.append(read_frame_outcome(msg)), RESULT_QOS)
    nodes += [probe, listener]
    for node in nodes:
        executor.add_node(node)
    assert _spin_until(executor, lambda: probe._outcomes.get_subscription_count() > 0)
    probe._on_views(_views(1_000_000_000))          # processed: waits for release
    assert _spin_until(executor, lambda: probe._busy)
    probe._on_views(_views(2_000_000_000))          # pending, then fails
    probe._on_views(_views(3_000_000_000))          # replaces 2 while 1 runs: 2 is dropped
    probe._on_views(_views(2_000_000_000))          # replaces 3: 3 is dropped; 2 fails
    release.set()
    assert _spin_until(executor, lambda: len(heard) == 4)
    assert heard == [
        (2_000_000_000, 'dropped'), (3_000_000_000, 'dropped'),
        (1_000_000_000, 'done'), (2_000_000_000, 'failed')]


def rclpy_node(name: str):
    from rclpy.node import Node

    return Node(name)


def test_the_localiser_admits_only_while_fewer_than_max_in_flight_are_unfinished(ros):
    from rclpy.parameter import Parameter

    from tlessbot_ros.conversions.outcomes import frame_outcome
    from tlessbot_ros.nodes.common import RESULT_QOS, message_class
    from tlessbot_ros.nodes.localiser import LocaliserNode

    executor, nodes = ros
    localiser = LocaliserNode(parameter_overrides=[
        Parameter('admission.max_in_flight', value=1),
        Parameter('admission.hold_newest', value=False)])
    nodes.append(localiser)
    executor.add_node(localiser)
    # No pose estimator reports outcomes yet: nothing to wait for, every frame is taken.
    assert localiser.admit(_views(1)) and localiser.admit(_views(2))
    assert localiser.in_flight.open_count == 0

    downstream = rclpy_node('fake_stages')
    header = message_class('std_msgs/msg/Header')
    pose_outcomes = downstream.create_publisher(header, '/pose_estimator/frames', RESULT_QOS)
    classifier_outcomes = downstream.create_publisher(header, '/classifier/frames', RESULT_QOS)
    nodes.append(downstream)
    executor.add_node(downstream)
    assert _spin_until(executor, lambda: pose_outcomes.get_subscription_count() > 0
                       and classifier_outcomes.get_subscription_count() > 0
                       and localiser._downstream['pose_estimator'].get_publisher_count() > 0)

    assert localiser.admit(_views(10))
    assert not localiser.admit(_views(11))           # frame 10 is still in the graph
    handled = []   # outcomes the localiser has taken in, so the test waits for a signal
    take_in = localiser._on_downstream_outcome
    localiser._on_downstream_outcome = lambda stage, msg: (take_in(stage, msg),
                                                           handled.append(stage))
    classifier_outcomes.publish(frame_outcome(10, 'done'))   # not the last stage: still open
    pose_outcomes.publish(frame_outcome(99, 'done'))         # not ours: ignored
    assert _spin_until(executor, lambda: len(handled) == 2)
    assert localiser.in_flight.open_count == 1
    pose_outcomes.publish(frame_outcome(10, 'done'))
    assert _spin_until(executor, lambda: localiser.in_flight.open_count == 0)
    assert localiser.admit(_views(12))
    classifier_outcomes.publish(frame_outcome(12, 'dropped'))  # never reaches the pose stage
    assert _spin_until(executor, lambda: localiser.in_flight.open_count == 0)
    assert localiser.in_flight.refused == 1


def test_a_refused_frame_waits_at_the_entrance_and_is_taken_when_a_slot_frees(ros):
    """With admission.hold_newest (the default) the newest refused frame is not lost: the
    outcome that frees a slot hands it to the worker; an older waiting frame is dropped."""
    from rclpy.parameter import Parameter

    from tlessbot_ros.conversions.outcomes import frame_outcome
    from tlessbot_ros.nodes.common import RESULT_QOS, message_class
    from tlessbot_ros.nodes.inputs import newest_stamp_ns
    from tlessbot_ros.nodes.localiser import LocaliserNode

    executor, nodes = ros
    localiser = LocaliserNode(parameter_overrides=[Parameter('admission.max_in_flight', value=1)])
    nodes.append(localiser)
    executor.add_node(localiser)
    taken = []
    localiser.take_frame = lambda views, held=False: taken.append(newest_stamp_ns(views))
    downstream = rclpy_node('fake_pose_stage')
    pose_outcomes = downstream.create_publisher(message_class('std_msgs/msg/Header'),
                                                '/pose_estimator/frames', RESULT_QOS)
    nodes.append(downstream)
    executor.add_node(downstream)
    assert _spin_until(executor, lambda: pose_outcomes.get_subscription_count() > 0
                       and localiser._downstream['pose_estimator'].get_publisher_count() > 0)

    assert localiser.admit(_views(10))
    assert not localiser.admit(_views(11)) and not localiser.admit(_views(12))
    assert localiser.entrance_dropped == 1            # 11, replaced by 12; 12 waits
    assert localiser.in_flight.waiting_stamp_ns == 12
    pose_outcomes.publish(frame_outcome(10, 'done'))
    assert _spin_until(executor, lambda: taken == [12])
    assert localiser.in_flight.open_count == 1 and localiser.in_flight.released == 1
    localiser.set_parameters([Parameter('admission.hold_newest', value=False)])
    localiser.parameters.apply_pending()   # what the worker does before its next frame
    assert not localiser.admit(_views(13))
    assert localiser.entrance_dropped == 2 and localiser.in_flight.waiting_stamp_ns is None
