"""The objects node over DDS: a stand-in pose stage publishes unnamed frames, an arm-like
client asks GetObjects and composes world -> part from /tf_static and /tf."""
import sys
import threading
import time

import numpy as np
import pytest
from running import Running

from tlessbot_ros.conversions.detections import PartPose, parts_to_detection_array
from tlessbot_ros.conversions.messages import RclpyFactory
from tlessbot_ros.conversions.topics import DETECTIONS, RAW_DETECTIONS
from tlessbot_ros.core.common.geometry import make_transform, rotation_about_axis

pytestmark = pytest.mark.ros
SECOND = 1_000_000_000


def part(name, x, y, yaw_deg=0.0):
    R = rotation_about_axis(np.array([0, 0, 1.0]), np.radians(yaw_deg))
    return PartPose(name, make_transform(R, np.array([x, y, 0.02])), 'world', 0.9,
                    np.array([0.05, 0.04, 0.03]))


@pytest.fixture
def graph():
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from vision_msgs.msg import Detection3DArray

    from tlessbot_ros.nodes.common import RESULT_QOS
    from tlessbot_ros.tools.support.arm_client import ArmClient

    node_process = Running([sys.executable, '-m', 'tlessbot_ros.nodes.objects', '--ros-args',
                            '-p', 'track.ttl_s:=1.0'])
    rclpy.init()
    node = rclpy.create_node('objects_test')
    publisher = node.create_publisher(Detection3DArray, RAW_DETECTIONS, RESULT_QOS)
    named = []
    node.create_subscription(Detection3DArray, DETECTIONS, named.append, RESULT_QOS)
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    spinner = threading.Thread(target=executor.spin, daemon=True)
    spinner.start()
    client = ArmClient(node)
    assert client.wait_for_service(60.0), node_process.output
    deadline = time.monotonic() + 30
    while publisher.get_subscription_count() == 0 and time.monotonic() < deadline:
        time.sleep(0.05)

    def publish(stamp_ns, parts):
        publisher.publish(parts_to_detection_array(parts, frame_id='world', stamp_ns=stamp_ns,
                                                   factory=RclpyFactory()))
    yield client, publish, named, node
    executor.shutdown(timeout_sec=1.0)
    node.destroy_node()
    rclpy.try_shutdown()
    node_process.interrupt()


def ask(client, publish, stamp_ns, frame_parts, **kwargs):
    """A request, answered by the frame published after it arrived."""
    result = {}
    thread = threading.Thread(target=lambda: result.update(a=client.request(**kwargs)))
    thread.start()
    time.sleep(0.3)   # the request reaches the node before the frame
    publish(stamp_ns, frame_parts)
    thread.join(30)
    return result['a']


def test_request_tf_names_and_timeout(graph):
    client, publish, named, _ = graph
    scene = [part('obj_05', 0.0, 0.0), part('obj_05', 0.1, 0.0, 30), part('obj_07', 0.0, 0.1)]
    first = ask(client, publish, 1 * SECOND, scene, frame_id='side_color_optical_frame')
    assert first.success, first.message
    assert sorted(p.instance for p in first.parts) == ['obj_05_1', 'obj_05_2', 'obj_07_1']
    assert first.stamp_ns == 1 * SECOND
    for answer in first.parts:
        assert answer.frame_id == 'side_color_optical_frame'
        truth = min(scene, key=lambda p: np.linalg.norm(p.T[:3, 3] -
                                                        answer.T_world_part_tf[:3, 3])).T
        # TF (world -> side optical frame, side frame -> instance) gives the world pose
        np.testing.assert_allclose(answer.T_world_part_tf, truth, atol=1e-6)
        parent, T_world_side = client.static['side_color_optical_frame']
        assert parent == 'world'
        np.testing.assert_allclose(T_world_side @ answer.T_frame_part, truth, atol=1e-6)
    # the parts rest (noise), the second obj_05 moves 8 cm, obj_07 goes, obj_09 comes
    moved = [part('obj_05', 0.002, 0.0), part('obj_05', 0.1, 0.08, 30), part('obj_09', -0.1, 0)]
    second = ask(client, publish, SECOND + SECOND // 2, moved, parts=['obj_05'])
    assert sorted(p.instance for p in second.parts) == ['obj_05_1', 'obj_05_3']
    # an empty frame is an empty array with the source stamp
    publish(3 * SECOND, [])
    deadline = time.monotonic() + 10
    while not any(m.header.stamp.sec == 3 for m in named) and time.monotonic() < deadline:
        time.sleep(0.05)
    empty = [m for m in named if m.header.stamp.sec == 3]
    assert empty and list(empty[0].detections) == []
    assert any(d.id == 'obj_05_2' for m in named for d in m.detections)
    # the agreement of two frames: obj_09 is in one of them only
    result = {}
    thread = threading.Thread(target=lambda: result.update(a=client.request(frames=2)))
    thread.start()
    time.sleep(0.3)
    publish(3 * SECOND + SECOND // 10, moved)
    publish(3 * SECOND + SECOND // 5, moved[:2])
    thread.join(30)
    assert sorted(p.part for p in result['a'].parts) == ['obj_05', 'obj_05']   # no obj_09
    # no frame: a clear error within the timeout
    late = client.request(timeout_s=0.5)
    assert not late.success and 'no frame completed within 0.5 s' in late.message
    wrong = client.request(frame_id='nowhere', timeout_s=0.5)
    assert not wrong.success and "unknown frame 'nowhere'" in wrong.message


def test_tf_static_follows_the_observed_rig(graph):
    from geometry_msgs.msg import PoseArray

    from tlessbot_ros.conversions.pose import camera_poses_to_pose_array
    from tlessbot_ros.conversions.topics import OBSERVED_RIG
    from tlessbot_ros.nodes.stage_config import RIG_QOS

    client, _, _, node = graph
    deadline = time.monotonic() + 30
    while 'top_color_optical_frame' not in client.static and time.monotonic() < deadline:
        time.sleep(0.05)
    _, T_top = client.static['top_color_optical_frame']
    _, T_side = client.static['side_color_optical_frame']
    moved = {'top': T_top @ make_transform(np.eye(3), np.array([0.01, 0.0, 0.0])),
             'side': T_side}
    publisher = node.create_publisher(PoseArray, OBSERVED_RIG, RIG_QOS)
    publisher.publish(camera_poses_to_pose_array(moved, names=('top', 'side'), frame_id='world',
                                                 factory=RclpyFactory()))
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline and not np.allclose(
            client.static['top_color_optical_frame'][1], moved['top'], atol=1e-6):
        time.sleep(0.05)
    np.testing.assert_allclose(client.static['top_color_optical_frame'][1], moved['top'],
                               atol=1e-6)
    np.testing.assert_allclose(client.static['side_color_optical_frame'][1], T_side, atol=1e-6)
