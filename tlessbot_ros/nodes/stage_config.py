"""What every stage node declares and reads at start-up: its cameras (``rig.cameras``), their
poses (``rig.CAMERA.*``, live), where its images come from (``input_source``), which camera
poses it follows (``rig_source``), its inputs' QoS (``input_qos``, ``input_depth``) and
``parallel.*``; and the input topics a stage subscribes (:func:`camera_inputs`)."""
from __future__ import annotations

from collections.abc import Callable, Sequence
from functools import partial
from typing import TYPE_CHECKING, Any

import numpy as np
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from tlessbot_ros.conversions.messages import message_class
from tlessbot_ros.conversions.topics import (
    COLOR,
    DEPTH,
    DEPTH_INFO,
    OBSERVED_RIG,
    camera_topic,
    relay_topic,
)
from tlessbot_ros.core.common import (
    CAMERA_NAMES,
    SIDE,
    TOP,
    CameraMount,
    Rig,
    check_camera_roles,
    default_rig,
    look_at,
)
from tlessbot_ros.errors import TlessbotError
from tlessbot_ros.nodes.parameters import LiveParameters
from tlessbot_ros.nodes.qos import RESULT_QOS, SENSOR_QOS
from tlessbot_ros.parallel.spare_cpu import SpareCpu, SpareCpuParams

if TYPE_CHECKING:
    from tlessbot_ros.nodes.stage import StageNode

IMAGE = 'sensor_msgs/msg/Image'
CAMERA_INFO = 'sensor_msgs/msg/CameraInfo'
# StageNode.setup_inputs entries of the camera topics: input key -> (type, camera-relative topic)
CAMERA_INPUTS = {'color': (IMAGE, COLOR), 'depth': (IMAGE, DEPTH),
                 'info': (CAMERA_INFO, DEPTH_INFO)}
INPUT_SOURCES = ('localiser', 'cameras')
RIG_SOURCES = ('localiser', 'config')
# The observed rig changes rarely and a stage that starts late must still get the latest.
RIG_QOS = QoSProfile(reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL,
                     history=HistoryPolicy.KEEP_LAST, depth=1)


def camera_inputs(keys: Sequence[str], source: str = 'cameras'
                  ) -> dict[str, tuple[str, Callable[[str], str]]]:
    """``setup_inputs`` entries of the camera inputs ``keys`` (color, depth, info), read from
    the cameras' topics or from the localiser's relay of the frames it admitted."""
    if source not in INPUT_SOURCES:
        raise TlessbotError(f'input_source must be one of {INPUT_SOURCES}, got {source!r}')
    topic = camera_topic if source == 'cameras' else relay_topic
    return {key: (CAMERA_INPUTS[key][0], partial(topic, relative=CAMERA_INPUTS[key][1]))
            for key in keys}


def declare_input_source(node: StageNode) -> str:
    """Declare the read-only ``input_source`` of a stage after the localiser and return it.

    Raises:
        TlessbotError: a source other than :data:`INPUT_SOURCES`.
    """
    source = node.parameters.read_only('input_source', INPUT_SOURCES[0], (
        "where the camera images come from: 'localiser' (its relay of the frames it admitted) "
        "or 'cameras' (every frame of the camera topics)"))
    if source not in INPUT_SOURCES:
        raise TlessbotError(f'input_source must be one of {INPUT_SOURCES}, got {source!r}')
    return source


def follow_observed_rig(node: StageNode) -> str:
    """Declare the read-only ``rig_source`` of a stage after the localiser and, for
    'localiser', subscribe to the camera poses it publishes (:data:`OBSERVED_RIG`) when it
    fuses with a rig refined from the scene: :meth:`StageNode.camera_pose` then gives them."""
    source = node.parameters.read_only('rig_source', RIG_SOURCES[0], (
        "the camera poses of the views: 'localiser' (its refined rig on /localiser/rig, "
        "rig.CAMERA.* until then) or 'config' (rig.CAMERA.* always)"))
    if source not in RIG_SOURCES:
        raise TlessbotError(f'rig_source must be one of {RIG_SOURCES}, got {source!r}')
    if source == 'localiser':
        node.create_subscription(message_class('geometry_msgs/msg/PoseArray'), OBSERVED_RIG,
                                 node.on_observed_rig, RIG_QOS)
    return source


def declare_spare_cpu(node: StageNode) -> SpareCpu:
    """Declare ``parallel.*`` (:class:`~tlessbot_ros.parallel.spare_cpu.SpareCpuParams`, live)
    and return the node's :class:`~tlessbot_ros.parallel.spare_cpu.SpareCpu`: whether a frame's
    work may be split over a second thread or process."""
    spare = SpareCpu()
    spare.params = node.parameters.dataclass(SpareCpuParams(), prefix='parallel.',
                                             apply=partial(setattr, spare, 'params'))
    return spare


def declare_cameras(parameters: LiveParameters) -> tuple[str, ...]:
    """Declare ``rig.cameras`` (read-only; default :data:`~tlessbot_ros.core.common.CAMERA_NAMES`)
    and return it.

    Raises:
        CalibrationError: neither the two roles the pipeline fuses nor one camera.
    """
    names = parameters.read_only('rig.cameras', list(CAMERA_NAMES), f'names of the cameras of '
                                 f'the rig: the roles {list(CAMERA_NAMES)} in any order, or '
                                 'one camera of any name')
    return check_camera_roles(names)


def declare_extrinsics(parameters: LiveParameters, cameras: Sequence[str],
                       apply: Callable[[str, np.ndarray], None]) -> dict[str, np.ndarray]:
    """Declare ``rig.<camera>.{position_m, look_at_m, up}`` (defaults: the paper's cell; a
    camera named other than ``top`` gets the side camera's) and return {camera: T_world_camera}.
    Intrinsics come from the live CameraInfo instead.

    They are live: a change reaches ``apply(camera, T_world_camera)`` between frames."""
    defaults = default_rig()
    extrinsics = {}
    for camera in cameras:
        names = {key: f'rig.{camera}.{key}' for key in ('position_m', 'look_at_m', 'up')}
        default = defaults[camera if camera == TOP else SIDE].T_world_camera
        declarations = {
            names['position_m']: ([float(v) for v in default[:3, 3]],
                                  f'{camera} camera position in the world (table) frame, metres'),
            names['look_at_m']: ([0.0, 0.0, 0.0],
                                 f'point the {camera} camera looks at, world frame, metres'),
            names['up']: ([0.0, 1.0, 0.0] if camera == TOP else [0.0, 0.0, 1.0],
                          f'world direction shown at the top of the {camera} image')}
        extrinsics[camera] = parameters.group(
            declarations, build=partial(_camera_pose, names),
            apply=partial(apply, camera))
    return extrinsics


def _camera_pose(names: dict[str, str], values: dict[str, Any]) -> np.ndarray:
    """T_world_camera from a camera's ``position_m``, ``look_at_m`` and ``up`` parameters.

    Raises:
        ValueError: not three finite numbers each, the camera on its target, or ``up`` along
            the viewing direction.
    """
    points = {}
    for key, name in names.items():
        point = np.asarray(values[name], dtype=np.float64)
        if point.shape != (3,) or not np.all(np.isfinite(point)):
            raise ValueError(f'{name} must be three finite numbers [x, y, z], got '
                             f'{list(values[name])}')
        points[key] = point
    if np.linalg.norm(points['look_at_m'] - points['position_m']) < 1e-9:
        raise ValueError(f'{names["position_m"]} and {names["look_at_m"]} coincide: the camera '
                         'must look at a point away from it')
    try:
        return look_at(points['position_m'], points['look_at_m'], points['up'])
    except ValueError as error:
        raise ValueError(f'{names["up"]}: {error}') from None


def input_profile(input_qos: str, depth: int) -> QoSProfile:
    """A stage's subscription QoS: the reliability of ``input_qos`` ('sensor_data' or
    'reliable'), VOLATILE (a new subscriber gets no sample written before it matched), and
    ``depth`` samples of history."""
    base = SENSOR_QOS if input_qos == 'sensor_data' else RESULT_QOS
    return QoSProfile(reliability=base.reliability, durability=base.durability,
                      history=HistoryPolicy.KEEP_LAST, depth=max(1, int(depth)))


def rig_with_intrinsics(extrinsics: dict[str, np.ndarray], intrinsics: dict[str, Any]) -> Rig:
    """A Rig from configured extrinsics and the intrinsics of the current CameraInfos."""
    return Rig(cameras={c: CameraMount(c, intrinsics[c], extrinsics[c]) for c in intrinsics})


def declare_input_qos(parameters: LiveParameters) -> tuple[str, int]:
    """Declare the read-only ``input_qos`` and ``input_depth`` and return them.

    Raises:
        TlessbotError: a QoS other than 'sensor_data' or 'reliable'.
    """
    input_qos = parameters.read_only('input_qos', 'sensor_data', (
        "QoS of the subscriptions: 'sensor_data' (best effort, the ROS convention for "
        "camera streams) or 'reliable' (no loss of large images under CPU load)"))
    input_depth = parameters.read_only('input_depth', 2, (
        'History depth of each subscription: a node that falls behind drops the older '
        'frames instead of queueing them (latency stays bounded)'))
    if input_qos not in ('sensor_data', 'reliable'):
        raise TlessbotError(f"input_qos must be 'sensor_data' or 'reliable', got "
                            f'{input_qos!r}')
    return input_qos, input_depth
