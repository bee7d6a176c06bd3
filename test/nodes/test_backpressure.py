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
def ros(request):
    """(executor, nodes to destroy); the executor is named as sync.executor: a test
    parametrised with ``indirect=['ros']`` picks it, else 'single_threaded'."""
    import rclpy

    from tlessbot_ros.nodes.common import make_executor

    rclpy.init()
    executor = make_executor(getattr(request, 'param', 'single_threaded'), None)
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


def _fake_downstream(ros, localiser):
    """A node publishing the classifier's and the pose estimator's outcomes, matched with
    ``localiser``'s subscriptions: (pose outcomes, classifier outcomes) publishers."""
    from tlessbot_ros.nodes.common import RESULT_QOS, message_class

    executor, nodes = ros
    downstream = rclpy_node('fake_stages')
    header = message_class('std_msgs/msg/Header')
    pose_outcomes = downstream.create_publisher(header, '/pose_estimator/frames', RESULT_QOS)
    classifier_outcomes = downstream.create_publisher(header, '/classifier/frames', RESULT_QOS)
    nodes.append(downstream)
    executor.add_node(downstream)
    assert _spin_until(executor, lambda: pose_outcomes.get_subscription_count() > 0
                       and classifier_outcomes.get_subscription_count() > 0
                       and all(localiser._downstream[stage].get_publisher_count() > 0
                               for stage in ('classifier', 'pose_estimator')))
    return pose_outcomes, classifier_outcomes


def test_the_localiser_admits_only_while_fewer_than_max_in_flight_are_unfinished(ros):
    from rclpy.parameter import Parameter

    from tlessbot_ros.conversions.outcomes import frame_outcome
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

    pose_outcomes, classifier_outcomes = _fake_downstream(ros, localiser)

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


def test_a_second_frame_enters_once_the_classifier_has_passed_the_first_on(ros):
    """admission.pipeline_behind_last_stage: with two frames allowed in flight, the second
    enters only once the classifier reported the first done (it is with the pose estimator)."""
    from rclpy.parameter import Parameter

    from tlessbot_ros.conversions.outcomes import frame_outcome
    from tlessbot_ros.nodes.localiser import LocaliserNode

    executor, nodes = ros
    localiser = LocaliserNode(parameter_overrides=[
        Parameter('admission.max_in_flight', value=2),
        Parameter('admission.pipeline_min_spare_cores', value=0.0),
        Parameter('admission.hold_newest', value=False)])
    nodes.append(localiser)
    executor.add_node(localiser)
    pose_outcomes, classifier_outcomes = _fake_downstream(ros, localiser)
    assert localiser.admit(_views(10))
    assert not localiser.admit(_views(11))             # frame 10 is before the pose stage
    classifier_outcomes.publish(frame_outcome(10, 'done'))
    assert _spin_until(executor, lambda: 10 in localiser.in_flight._at_last_stage)
    assert localiser.admit(_views(12))                 # it follows frame 10 in
    assert not localiser.admit(_views(13))             # two in flight
    pose_outcomes.publish(frame_outcome(10, 'done'))
    assert _spin_until(executor, lambda: localiser.in_flight.open_count == 1)
    assert not localiser.admit(_views(14))             # frame 12 is before the pose stage
    localiser.set_parameters([Parameter('admission.pipeline_behind_last_stage', value=False)])
    localiser.parameters.apply_pending()
    assert localiser.admit(_views(15))


def _localiser_taking_into(ros, taken: list, *parameters):
    """A localiser with one frame in flight (and ``parameters``) whose taken frames' stamps go
    to ``taken``, and a node publishing the pose estimator's outcomes: (localiser, that node,
    its publisher)."""
    from rclpy.parameter import Parameter

    from tlessbot_ros.nodes.common import RESULT_QOS, message_class
    from tlessbot_ros.nodes.inputs import newest_stamp_ns
    from tlessbot_ros.nodes.localiser import LocaliserNode

    executor, nodes = ros
    localiser = LocaliserNode(parameter_overrides=[Parameter('admission.max_in_flight', value=1),
                                                   *parameters])
    nodes.append(localiser)
    executor.add_node(localiser)
    localiser.take_frame = lambda views, held=False: taken.append(newest_stamp_ns(views))
    downstream = rclpy_node('fake_pose_stage')
    pose_outcomes = downstream.create_publisher(message_class('std_msgs/msg/Header'),
                                                '/pose_estimator/frames', RESULT_QOS)
    nodes.append(downstream)
    executor.add_node(downstream)
    return localiser, downstream, pose_outcomes


def test_a_refused_frame_waits_at_the_entrance_and_is_taken_when_a_slot_frees(ros):
    """With admission.hold_newest (the default) the newest refused frame is not lost: the
    outcome that frees a slot hands it to the worker; an older waiting frame is dropped."""
    from rclpy.parameter import Parameter

    from tlessbot_ros.conversions.outcomes import frame_outcome

    executor, _ = ros
    taken = []
    localiser, _, pose_outcomes = _localiser_taking_into(ros, taken)
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


def _publish_camera_frame(publishers: dict, stamp_ns: int) -> None:
    """One tiny frame (colour, aligned depth, camera_info) on every camera's topics."""
    from tlessbot_ros.conversions.camera_info import intrinsics_to_camera_info
    from tlessbot_ros.conversions.image_cdr import image_to_cdr
    from tlessbot_ros.conversions.messages import RclpyFactory
    from tlessbot_ros.core.common import d415_intrinsics

    for camera, topics in publishers.items():
        frame = f'{camera}_color_optical_frame'
        topics['color'].publish(image_to_cdr(np.zeros((6, 8, 3), np.uint8), 'rgb8',
                                             frame_id=frame, stamp_ns=stamp_ns))
        topics['depth'].publish(image_to_cdr(np.full((6, 8), 500, np.uint16), '16UC1',
                                             frame_id=frame, stamp_ns=stamp_ns))
        topics['info'].publish(intrinsics_to_camera_info(
            d415_intrinsics(8, 6), frame_id=frame, stamp_ns=stamp_ns, factory=RclpyFactory()))


@pytest.mark.parametrize('ros, executor_kind', [('single_threaded', 'single_threaded'),
                                                ('events', 'events')], indirect=['ros'])
def test_a_full_entrance_leaves_camera_messages_unread_and_takes_the_newest_when_a_slot_frees(
        ros, executor_kind):
    """admission.pause_inputs (the default): while max_in_flight frames are open, the camera
    subscriptions are not read at all (nothing is paired or refused); the outcome that frees a
    slot reads what waited in DDS and takes only its newest complete frame. With it off, every
    message is read and each complete frame is refused on its own. The same with rclpy's
    EventsExecutor (sync.executor 'events'), which delivers every message while the entrance
    is full: the localiser keeps them, as many per topic as DDS would, unread."""
    from rclpy.duration import Duration
    from rclpy.parameter import Parameter

    from tlessbot_ros.conversions.outcomes import frame_outcome
    from tlessbot_ros.conversions.topics import camera_topic
    from tlessbot_ros.nodes.common import RESULT_QOS, message_class
    from tlessbot_ros.nodes.stage import CAMERA_INPUTS

    executor, _ = ros
    taken = []
    # reliable inputs: a publisher then knows when the localiser's readers hold its frames
    localiser, cameras, pose_outcomes = _localiser_taking_into(
        ros, taken, Parameter('input_qos', value='reliable'),
        Parameter('sync.executor', value=executor_kind))
    publishers = {camera: {key: cameras.create_publisher(message_class(msg_type),
                                                         camera_topic(camera, topic), RESULT_QOS)
                           for key, (msg_type, topic) in CAMERA_INPUTS.items()}
                  for camera in ('top', 'side')}
    assert _spin_until(executor, localiser.ready.is_set, timeout_s=120.0)
    assert _spin_until(executor, lambda: pose_outcomes.get_subscription_count() > 0
                       and localiser._downstream['pose_estimator'].get_publisher_count() > 0
                       and all(p.get_subscription_count() > 0
                               for topics in publishers.values() for p in topics.values()))
    second = 1_000_000_000
    _publish_camera_frame(publishers, 1 * second)   # the entrance is open: taken at once
    assert _spin_until(executor, lambda: taken == [1 * second])
    inputs = localiser._inputs
    for stamp in (2, 3, 4):   # a frame is open: these wait in DDS, unread
        _publish_camera_frame(publishers, stamp * second)
        executor.spin_once(timeout_sec=0.05)
    assert all(p.wait_for_all_acked(Duration(seconds=60))   # in the localiser's readers
               for topics in publishers.values() for p in topics.values())
    executor.spin_once(timeout_sec=0.05)
    assert taken == [1 * second] and localiser.in_flight.refused == 0
    assert sum(inputs._per_camera['top'].pending().values()) == 0   # none was read
    pose_outcomes.publish(frame_outcome(1 * second, 'done'))
    assert _spin_until(executor, lambda: len(taken) == 2)   # one read takes all that waited
    assert taken == [1 * second, 4 * second]       # the newest; 3 read and dropped (depth 2)
    assert inputs.superseded == 1 and localiser.in_flight.refused == 0
    assert inputs.unread_estimate == 1             # frame 2 was replaced in DDS, never read

    localiser.set_parameters([Parameter('admission.pause_inputs', value=False)])
    localiser.parameters.apply_pending()
    assert _spin_until(executor, lambda: not inputs._reopening)   # the change read: none
    for stamp in (5, 6):   # frame 4 is open: both are read, and each is refused
        _publish_camera_frame(publishers, stamp * second)
        assert _spin_until(executor, lambda n=stamp - 4: localiser.in_flight.refused == n)
    assert taken == [1 * second, 4 * second] and inputs.superseded == 1
