"""Simulated two-view frames as a rosbag2 bag (mcap) with the camera drivers' topics.

Topics, per camera NAME in the rig (``top``, ``side``), as ``camera_driver`` publishes them:
``/NAME/color/image_raw`` (rgb8), ``/NAME/color/camera_info``,
``/NAME/aligned_depth_to_color/image_raw`` (16UC1, mm),
``/NAME/aligned_depth_to_color/camera_info`` and ``/NAME/depth/color/points`` (PointCloud2,
realsense-ros layout), all in ``NAME_color_optical_frame``. Ground truth:

- ``/ground_truth/obj_NN`` (geometry_msgs/PoseStamped): the pose of every instance of object NN,
  once per camera, in that camera's optical frame (``header.frame_id`` tells which);
- ``/ground_truth/info`` (diagnostic_msgs/DiagnosticArray): one status per instance, named
  ``obj_NN/INDEX``, with key-values ``obj_id``, ``instance``, and per camera
  ``visib_fract_NAME`` and ``bbox_visib_NAME`` (x y w h, pixels).

Frame i is stamped ``start_ns + i / fps``; every message of a frame carries that stamp, and the
bag's log time equals it.
"""
from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from tlessbot_ros.conversions.camera import camera_frame_messages
from tlessbot_ros.conversions.messages import MessageFactory, RosbagsFactory, make_header
from tlessbot_ros.conversions.pose import transform_to_pose_stamped
from tlessbot_ros.io.bag_writer import RELIABLE_OFFER, BagWriter

GROUND_TRUTH_INFO_TOPIC = '/ground_truth/info'


def ground_truth_topic(obj_id: int) -> str:
    return f'/ground_truth/obj_{obj_id:02d}'


@dataclass(frozen=True)
class BagParams:
    """Bag writing options.

    Attributes:
        fps: frame rate; frame i is stamped ``start_ns + i / fps``.
        start_ns: stamp of the first frame (ROS time, ns).
        cloud_stride: pixel stride of the point clouds (1 = every valid pixel, as a D415;
            larger values keep demo bags small).
        with_clouds: write ``depth/color/points``.
        compress: zstd-compress the mcap file's chunks (messages inside stay plain CDR, so
            every MCAP reader decodes them).
        with_ground_truth: write the ground-truth topics (off: the cameras' topics alone, as
            a recording of the cell holds).
    """

    fps: float = 15.0
    start_ns: int = 1_700_000_000_000_000_000
    cloud_stride: int = 1
    with_clouds: bool = True
    compress: bool = True
    with_ground_truth: bool = True


def frame_messages(frame: Any, stamp_ns: int, *, params: BagParams,
                   factory: MessageFactory) -> list[tuple[str, Any]]:
    """(absolute topic, message) pairs of one simulated two-view frame."""
    messages: list[tuple[str, Any]] = []
    for name, view in frame.views.items():
        camera = camera_frame_messages(name, view.rgb, view.depth_mm, view.intrinsics, stamp_ns,
                                       with_cloud=params.with_clouds,
                                       cloud_stride=params.cloud_stride, factory=factory)
        messages += [(f'/{name}/{topic}', msg) for topic, msg in camera.items()]
    if not params.with_ground_truth:
        return messages
    statuses = []
    for index, placed in enumerate(frame.objects):
        values = {'obj_id': str(placed.obj_id), 'instance': str(index)}
        for name, view in frame.views.items():
            gt = view.gt[index]
            messages.append((ground_truth_topic(placed.obj_id), transform_to_pose_stamped(
                gt.T_camera_object, frame_id=f'{name}_color_optical_frame', stamp_ns=stamp_ns,
                factory=factory)))
            values[f'visib_fract_{name}'] = f'{gt.visib_fract:.4f}'
            values[f'bbox_visib_{name}'] = ' '.join(str(int(v)) for v in gt.bbox_visib)
        statuses.append(factory.new(
            'diagnostic_msgs/msg/DiagnosticStatus', level=0,
            name=f'obj_{placed.obj_id:02d}/{index}', message='ground truth',
            hardware_id='tlessbot_sim',
            values=[factory.new('diagnostic_msgs/msg/KeyValue', key=k, value=v)
                    for k, v in values.items()]))
    messages.append((GROUND_TRUTH_INFO_TOPIC, factory.new(
        'diagnostic_msgs/msg/DiagnosticArray', header=make_header('world', stamp_ns, factory),
        status=statuses)))
    return messages


def write_bag(frames: Iterable[Any], path: str | Path, *,
              params: BagParams = BagParams()) -> dict[str, int]:
    """Write simulated frames to a new mcap bag folder; returns message counts per topic.

    Every topic is offered as camera_driver offers it (:data:`RELIABLE_OFFER`).
    """
    factory = RosbagsFactory()
    typestore = factory.typestore
    with BagWriter(path, compress=params.compress, typestore=typestore) as bag:
        for index, frame in enumerate(frames):
            stamp_ns = params.start_ns + round(index * 1e9 / params.fps)
            for topic, msg in frame_messages(frame, stamp_ns, params=params, factory=factory):
                if topic not in bag.topics:
                    bag.add_topic(topic, msg.__msgtype__, [RELIABLE_OFFER])
                bag.write(topic, stamp_ns, typestore.serialize_cdr(msg, msg.__msgtype__))
    return bag.counts
