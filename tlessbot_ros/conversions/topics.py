"""Every topic name of the graph, defined once.

Camera topics are relative to a camera's namespace and follow realsense-ros with
``align_depth.enable:=true pointcloud.enable:=true``; :func:`camera_topic` gives the absolute
name. The stage topics carry the camera's name in the middle (``/localiser/top/labels``).
Camera names themselves come from the rig (:data:`~tlessbot_ros.core.common.CAMERA_NAMES`).
"""
from __future__ import annotations

from collections.abc import Mapping

from tlessbot_ros.core.common.names import part_name

COLOR = 'color/image_raw'
COLOR_INFO = 'color/camera_info'
DEPTH = 'aligned_depth_to_color/image_raw'
DEPTH_INFO = 'aligned_depth_to_color/camera_info'
POINTS = 'depth/color/points'
CAMERA_TOPICS = (COLOR, COLOR_INFO, DEPTH, DEPTH_INFO, POINTS)

DIAGNOSTICS = '/diagnostics'
MARKERS = '/objects/markers'
DEBUG_IMAGE = '/objects/debug_image'
GROUND_TRUTH_INFO = '/ground_truth/info'
GROUND_TRUTH_POSE_PREFIX = '/ground_truth/obj_'
# The camera poses the localiser fuses with once it refines the rig from the scene
# (geometry_msgs/PoseArray in the world frame: top, then side); the later stages follow them.
OBSERVED_RIG = '/localiser/rig'
# The arm's side (nodes/objects.py): every part of a frame, named; the pose stage's unnamed
# array it is made from; TF; the request service.
DETECTIONS = '/objects/detections'
RAW_DETECTIONS = '/pose_estimator/detections'
GET_OBJECTS = '/objects/get_objects'
TF = '/tf'
TF_STATIC = '/tf_static'


def node_relative(topic: str) -> str:
    """A graph topic as a name relative to the publishing node's namespace (the perception
    nodes publish their results so: in the root namespace, the absolute name)."""
    return topic.lstrip('/')


def camera_topic(camera: str, relative: str) -> str:
    """``/<camera>/<relative>``, e.g. ``camera_topic('top', COLOR)``."""
    return f'/{camera}/{relative}'


def labels_topic(camera: str) -> str:
    """The localiser's instance label image of one camera."""
    return f'/localiser/{camera}/labels'


def classes_topic(camera: str) -> str:
    """The classifier's class-instance image of one camera."""
    return f'/classifier/{camera}/classes'


def pose_topic(part: int | str, names: Mapping[int, str] | None = None) -> str:
    """The PoseStamped topic of one part, ``/objects/<name>/pose``: ``part`` is its name, or
    its id named by ``names`` (:func:`~tlessbot_ros.core.common.part_name`; T-LESS:
    ``/objects/obj_05/pose``)."""
    name = part if isinstance(part, str) else part_name(part, names)
    return f'/objects/{name}/pose'


def ground_truth_pose_topic(obj_id: int) -> str:
    """A simulated bag's ground-truth PoseStamped topic of one object."""
    return f'{GROUND_TRUTH_POSE_PREFIX}{obj_id:02d}'


def outcome_topic(stage: str) -> str:
    """Where a stage node reports what became of each frame it took (``/classifier/frames``):
    the localiser's backpressure listens to it (:mod:`~tlessbot_ros.conversions.outcomes`)."""
    return f'/{stage}/frames'


def relay_topic(camera: str, relative: str) -> str:
    """The localiser's copy of a camera topic, sent only for the frames it admits
    (``/localiser/top/color/image_raw``): the later stages subscribe to it instead of taking
    every camera frame only to keep the few they process."""
    return f'/localiser/{camera}/{relative}'
