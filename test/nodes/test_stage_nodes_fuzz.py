"""Each perception node survives malformed input, logs it, and still handles good frames.

The nodes run in this process (their callbacks are the real ones) and receive messages over
DDS from a publisher node. Bad cases: wrong encoding, sizes that disagree, empty data, all-NaN
and all-zero depth, an unknown frame id.
"""
from __future__ import annotations

import time

import numpy as np
import pytest

from tlessbot_ros.tools.support.garbage import corrupt_frames

pytestmark = pytest.mark.ros

CAMERAS = ('top', 'side')
STAMP0 = 1_700_000_000_000_000_000
AFTER_S = 8   # the good frame after the malformed ones (stamped STAMP0 + 0..5 s) comes later


@pytest.fixture(scope='module')
def sim_frame(tless_models_dir):
    from tlessbot_ros.io.models import load_models
    from tlessbot_ros.sim.simulator import SimParams, Simulator

    models = load_models(tless_models_dir, ids=[5, 21])
    sim = Simulator(models, params=SimParams(parts_min=2, parts_max=2), seed=11)
    return sim.frame(0)


@pytest.fixture(scope='module')
def model_files(tmp_path_factory, tless_models_dir):
    """A random-weight classifier and a one-object template database, written by our code."""
    from tlessbot_ros.core.common import default_rig
    from tlessbot_ros.core.pose import TemplateParams, build_database
    from tlessbot_ros.core.recognise import HogParams, LinearClassifier
    from tlessbot_ros.io.models import load_models, stable_poses

    folder = tmp_path_factory.mktemp('models')
    hog = HogParams()
    rng = np.random.default_rng(0)
    LinearClassifier(rng.normal(size=(hog.feature_dim, 2)).astype(np.float32),
                     np.zeros(2, np.float32), np.array([5, 21]), hog).save(folder / 'c.npz')
    model = load_models(tless_models_dir, ids=[5])[5]
    side = default_rig()['side']
    poses = [(p.T_table_object, p.probability) for p in stable_poses(model)]
    database = build_database([(5, model.vertices, model.faces, poses, model.diameter_m)],
                              intrinsics=side.intrinsics,
                              T_world_camera=side.T_world_camera,
                              params=TemplateParams(n_views=4))
    database.save(folder / 't.npz')
    return folder / 'c.npz', folder / 't.npz'


class Harness:
    """Publishes per-camera topics and spins the node under test plus a listener."""

    def __init__(self, node, topics: dict[str, str], outputs: list[str]):
        import rclpy
        from rclpy.executors import SingleThreadedExecutor

        from tlessbot_ros.nodes.common import RESULT_QOS, message_class

        self.node = node
        self.peer = rclpy.create_node('fuzz_peer')
        self.publishers = {}
        for camera in CAMERAS:
            for key, msgtype in topics.items():
                topic = key.format(camera=camera)
                self.publishers[topic] = self.peer.create_publisher(message_class(msgtype),
                                                                    topic, 10)
        self.received: dict[str, list] = {topic: [] for topic in outputs}
        for topic in outputs:
            self.peer.create_subscription(message_class('sensor_msgs/msg/Image'), topic,
                                          lambda msg, t=topic: self.received[t].append(msg),
                                          RESULT_QOS)
        self.executor = SingleThreadedExecutor()
        self.executor.add_node(node)
        self.executor.add_node(self.peer)
        self.spin(1.0)  # discovery

    def spin(self, seconds: float, until=None) -> None:
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            self.executor.spin_once(timeout_sec=0.05)
            if until is not None and until():
                return

    def publish(self, messages: dict[str, object]) -> None:
        """Publish the messages of the topics this harness publishes (others are ignored)."""
        for topic, msg in messages.items():
            if topic in self.publishers:
                self.publishers[topic].publish(msg)

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()
        self.peer.destroy_node()


def camera_messages(frame, stamp_ns: int) -> dict[str, object]:
    from tlessbot_ros.conversions.camera import camera_frame_messages

    out = {}
    for camera in CAMERAS:
        view = frame.views[camera]
        msgs = camera_frame_messages(camera, view.rgb, view.depth_mm, view.intrinsics, stamp_ns,
                                     with_cloud=False)
        out.update({f'/{camera}/{topic}': msg for topic, msg in msgs.items()})
    return out


def handled(node) -> int:
    """Frames processed or failed, and messages refused on arrival as malformed."""
    return node.failures + node.frames + node._inputs.malformed


def test_localiser_survives_malformed_input(sim_frame):
    import rclpy

    from tlessbot_ros.nodes.localiser import LocaliserNode

    rclpy.init()
    try:
        node = LocaliserNode()
        assert node.wait_ready()   # subscribed once warmed up
        harness = Harness(node, {'/{camera}/color/image_raw': 'sensor_msgs/msg/Image',
                                 '/{camera}/aligned_depth_to_color/image_raw':
                                     'sensor_msgs/msg/Image',
                                 '/{camera}/aligned_depth_to_color/camera_info':
                                     'sensor_msgs/msg/CameraInfo'},
                          ['/localiser/side/labels'])
        good = camera_messages(sim_frame, STAMP0)
        for name, msgs in corrupt_frames(good):
            before = handled(node)
            harness.publish(msgs)
            harness.spin(10.0, until=lambda b=before: handled(node) > b)
            assert handled(node) > before, f'{name}: frame never processed'
        assert node.failures >= 2  # encoding, size: errors, not crashes
        assert node._inputs.malformed >= 1   # empty data: refused before it is queued
        # a good frame after them (time goes on: a frame stamped before them would be held as
        # a possible time jump, SyncParams.jump_confirmations)
        harness.publish({key: _restamped(msg, AFTER_S) for key, msg in good.items()})
        harness.spin(15.0, until=lambda: any(
            m.header.stamp.sec == STAMP0 // 10**9 + AFTER_S for m in harness.received[
                '/localiser/side/labels']))
        labels = [m for m in harness.received['/localiser/side/labels']
                  if m.header.stamp.sec == STAMP0 // 10**9 + AFTER_S]
        assert labels and labels[0].encoding == '16UC1'
        assert labels[0].header.frame_id == 'side_color_optical_frame'
        # every frame's stamp is compared with the node's clock at the start of its
        # processing: the test stamps (2023) come from another clock, so no input age of years
        # is reported for them, only the clocks' offset
        assert node.other_clock_frames == node.frames + node.failures
        assert not node._input_ages_ms and node._stamp_offset_s > 86_400
        harness.close()
    finally:
        rclpy.try_shutdown()


def test_classifier_and_pose_estimator_survive_malformed_input(sim_frame, model_files):
    import rclpy
    from rclpy.parameter import Parameter

    from tlessbot_ros.conversions import array_to_image
    from tlessbot_ros.nodes.classifier import ClassifierNode
    from tlessbot_ros.nodes.pose_estimator import PoseEstimatorNode

    classifier_path, templates_path = model_files
    rclpy.init()
    try:
        good = camera_messages(sim_frame, STAMP0)
        for camera in CAMERAS:
            instance = sim_frame.views[camera].instance
            labels = np.where(instance >= 0, instance + 1, 0).astype(np.uint16)
            header = good[f'/{camera}/color/image_raw'].header
            good[f'/localiser/{camera}/labels'] = array_to_image(
                labels, '16UC1', frame_id=header.frame_id, stamp_ns=STAMP0)
            good[f'/classifier/{camera}/classes'] = array_to_image(
                ((labels > 0) * 5000 + labels).astype(np.uint16), '16UC1',
                frame_id=header.frame_id, stamp_ns=STAMP0)
        # fed straight from camera topics here, as when no localiser relays them
        node = ClassifierNode(parameter_overrides=[
            Parameter('model_path', value=str(classifier_path)),
            Parameter('input_source', value='cameras')])
        assert node.wait_ready()
        harness = Harness(node, {
            '/{camera}/color/image_raw': 'sensor_msgs/msg/Image',
            '/{camera}/aligned_depth_to_color/image_raw': 'sensor_msgs/msg/Image',
            '/{camera}/aligned_depth_to_color/camera_info': 'sensor_msgs/msg/CameraInfo',
            '/localiser/{camera}/labels': 'sensor_msgs/msg/Image'}, ['/classifier/side/classes'])
        bad = {key: _restamped(msg, 1) for key, msg in good.items()}
        bad['/localiser/side/labels'] = array_to_image(np.zeros((10, 10), np.uint8), 'mono8',
                                                       stamp_ns=STAMP0 + 10**9)
        harness.publish(bad)
        harness.spin(10.0, until=lambda: node.failures > 0)
        assert node.failures == 1  # wrong encoding and size: logged, not fatal
        harness.publish({key: _restamped(msg, AFTER_S) for key, msg in good.items()})
        harness.spin(15.0, until=lambda: harness.received['/classifier/side/classes'])
        classes = harness.received['/classifier/side/classes']
        assert classes and classes[0].encoding == '16UC3'   # three candidates per part
        harness.close()

        node = PoseEstimatorNode(parameter_overrides=[
            Parameter('templates_path', value=str(templates_path)),
            Parameter('input_source', value='cameras'),
            Parameter('workers.count', value=1),       # malformed frames reach the worker too
            Parameter('parallel.min_spare_cores', value=0.0)])   # on a busy host as well
        assert node.wait_ready()
        workers = list(node.workers._workers)
        harness = Harness(node, {
            '/{camera}/color/image_raw': 'sensor_msgs/msg/Image',
            '/{camera}/aligned_depth_to_color/image_raw': 'sensor_msgs/msg/Image',
            '/{camera}/aligned_depth_to_color/camera_info': 'sensor_msgs/msg/CameraInfo',
            '/classifier/{camera}/classes': 'sensor_msgs/msg/Image'}, [])
        for name, msgs in corrupt_frames(good):
            before = handled(node)
            harness.publish(msgs)
            harness.spin(10.0, until=lambda b=before: handled(node) > b)
            assert handled(node) > before, f'{name}: frame never processed'
        assert node.failures >= 1   # the size mismatch
        assert node._inputs.malformed >= 1   # empty data
        # RViz markers are built only while someone subscribes: subscribe, then send the frame
        from tlessbot_ros.nodes.common import RESULT_QOS, message_class
        markers = []
        harness.peer.create_subscription(message_class('visualization_msgs/msg/MarkerArray'),
                                         '/objects/markers', markers.append, RESULT_QOS)
        harness.spin(5.0, until=lambda: node._markers.get_subscription_count() > 0)
        frames_before = node.frames
        harness.publish({key: _restamped(msg, AFTER_S) for key, msg in good.items()})
        harness.spin(15.0, until=lambda: node.frames > frames_before and markers)
        assert node.frames > frames_before
        assert markers and markers[-1].markers[0].action == 3   # DELETEALL, then this frame's
        for marker in markers[-1].markers[1:]:
            assert marker.header.stamp.sec == STAMP0 // 10**9 + AFTER_S
        assert node.workers.worker_fits > 0 and node.workers.failures == 0
        harness.close()
        assert all(w.process.poll() is not None for w in workers)   # no process left behind
    finally:
        rclpy.try_shutdown()


def _restamped(msg, seconds: int):
    import copy

    out = copy.deepcopy(msg)
    out.header.stamp.sec += seconds
    return out
