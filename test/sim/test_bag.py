"""The simulator's bag: realsense-ros topics + ground truth, readable by rosbags and rclpy."""
from types import SimpleNamespace

import numpy as np
import pytest

from tlessbot_ros.conversions import image_to_array, pose_stamped_to_transform
from tlessbot_ros.core.common import d415_intrinsics, make_transform, rotation_about_axis
from tlessbot_ros.errors import BagError
from tlessbot_ros.io.bags import bag_topics, deserialize, read_bag
from tlessbot_ros.sim.bag import BagParams, write_bag

pytestmark = pytest.mark.rosbag


def _frame(seed: int):
    """A duck-typed SimulatedFrame with two views and two objects."""
    rng = np.random.default_rng(seed)
    intrinsics = d415_intrinsics(64, 48)
    objects = [SimpleNamespace(obj_id=5, T_world_object=np.eye(4)),
               SimpleNamespace(obj_id=21, T_world_object=np.eye(4))]
    views = {}
    for name in ('top', 'side'):
        gt = [SimpleNamespace(T_camera_object=make_transform(
            rotation_about_axis([0, 0, 1], 0.1 * k + seed), [0.01 * k, 0.0, 0.6 + seed * 0.01]),
            visib_fract=0.25 + 0.5 * k, bbox_visib=(1, 2, 3 + k, 4)) for k in range(2)]
        views[name] = SimpleNamespace(
            rgb=rng.integers(0, 256, (48, 64, 3), dtype=np.uint8),
            depth_mm=rng.integers(0, 1500, (48, 64)).astype(np.uint16),
            intrinsics=intrinsics, gt=gt)
    return SimpleNamespace(objects=objects, views=views)


@pytest.fixture(scope='module')
def bag(tmp_path_factory):
    frames = [_frame(i) for i in range(3)]
    path = tmp_path_factory.mktemp('bags') / 'sim'
    counts = write_bag(frames, path, params=BagParams(fps=10.0, cloud_stride=2))
    return path, frames, counts


def test_topics_and_counts(bag):
    path, _, counts = bag
    topics = bag_topics(path)
    for cam in ('top', 'side'):
        assert topics[f'/{cam}/color/image_raw'] == 'sensor_msgs/msg/Image'
        assert topics[f'/{cam}/aligned_depth_to_color/camera_info'] == \
            'sensor_msgs/msg/CameraInfo'
        assert topics[f'/{cam}/depth/color/points'] == 'sensor_msgs/msg/PointCloud2'
    assert topics['/ground_truth/obj_05'] == 'geometry_msgs/msg/PoseStamped'
    assert topics['/ground_truth/info'] == 'diagnostic_msgs/msg/DiagnosticArray'
    assert counts['/ground_truth/obj_21'] == 3 * 2  # 3 frames x 2 cameras
    assert counts['/side/color/image_raw'] == 3


def test_contents_and_stamps(bag):
    path, frames, _ = bag
    stamps = []
    for message in read_bag(path, ['/side/aligned_depth_to_color/image_raw',
                                   '/ground_truth/obj_05']):
        msg = deserialize(message)
        stamp = msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec
        assert stamp == message.log_time_ns
        index = round((stamp - BagParams().start_ns) / 1e8)  # 10 fps
        if message.msgtype == 'sensor_msgs/msg/Image':
            stamps.append(stamp)
            np.testing.assert_array_equal(image_to_array(msg),
                                          frames[index].views['side'].depth_mm)
        else:
            camera = msg.header.frame_id.split('_')[0]
            T, _, _ = pose_stamped_to_transform(msg)
            np.testing.assert_allclose(T, frames[index].views[camera].gt[0].T_camera_object,
                                       atol=1e-9)
    assert np.diff(stamps).tolist() == [100_000_000, 100_000_000]


@pytest.mark.ros
def test_rclpy_deserialises_every_message_type(bag):
    from rclpy.serialization import deserialize_message

    from tlessbot_ros.nodes.common import message_class

    seen = set()
    for message in read_bag(bag[0]):
        if message.msgtype in seen:
            continue
        msg = deserialize_message(message.raw, message_class(message.msgtype))
        assert msg.header.stamp.sec > 0
        seen.add(message.msgtype)
    assert seen == {'sensor_msgs/msg/Image', 'sensor_msgs/msg/CameraInfo',
                    'sensor_msgs/msg/PointCloud2', 'geometry_msgs/msg/PoseStamped',
                    'diagnostic_msgs/msg/DiagnosticArray'}


def test_refuses_to_overwrite(bag):
    with pytest.raises(BagError, match='exists'):
        write_bag([], bag[0])


def test_ground_truth_reads_back(bag):
    from tlessbot_ros.io.ground_truth import read_ground_truth

    path, frames, _ = bag
    truth = read_ground_truth(path)
    assert len(truth) == 3
    for stamp, instances in truth.items():
        index = round((stamp - BagParams().start_ns) / 1e8)
        assert [i.obj_id for i in instances] == [5, 21]
        for k, instance in enumerate(instances):
            assert instance.visib_fract['side'] == pytest.approx(0.25 + 0.5 * k)
            assert instance.bbox_visib['top'] == (1, 2, 3 + k, 4)
            np.testing.assert_allclose(
                instance.T_camera_object['side_color_optical_frame'],
                frames[index].views['side'].gt[k].T_camera_object, atol=1e-9)
    assert truth[BagParams().start_ns][1].max_visib_fract == pytest.approx(0.75)


def test_every_mcap_reader_decodes_it_and_topics_offer_what_camera_driver_offers(bag):
    from mcap_tools import decoded_messages

    from tlessbot_ros.io.bag_writer import RELIABLE_OFFER
    from tlessbot_ros.io.bags import bag_offered_qos

    path, _, counts = bag
    decoded = decoded_messages(path / 'sim.mcap')
    assert len(decoded) == sum(counts.values())
    assert {channel.topic for channel, _, _ in decoded} == set(counts)
    assert bag_offered_qos(path) == {topic: [RELIABLE_OFFER] for topic in counts}
