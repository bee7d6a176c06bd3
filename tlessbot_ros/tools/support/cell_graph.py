"""What a cell's perception graph is made of, as data (pure: nothing is started or imported
from ROS).

Two launchers start it: ``tlessbot launch`` (:func:`processes.graph_processes` turns each
:class:`GraphProcess` into an argv) and ``ros2 launch tlessbot_ros cell.launch.py`` (turns each
into a launch_ros ``Node`` or, for the replay, an ``ExecuteProcess``). Both give every ROS node
the same parameter file first, then the overrides listed here.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from tlessbot_ros.core.common.rig import CAMERA_NAMES
from tlessbot_ros.errors import TlessbotError

PERCEPTION_NODES = ('localiser', 'classifier', 'pose_estimator')
CAMERA_DRIVER = 'camera_driver'
# The arm's side: instance names, TF, /objects/detections, GetObjects (nodes/objects.py).
ARM_NODE = 'objects'
NODE_EXECUTABLES = (CAMERA_DRIVER, *PERCEPTION_NODES, ARM_NODE)
PARTS_NODES = ('localiser', 'classifier', 'pose_estimator', ARM_NODE)   # read ``parts_path``
# Started only when asked (foxglove:=true, tlessbot launch --foxglove): the live view.
FOXGLOVE_NODE = 'foxglove_view'
TOOL_EXECUTABLE = 'tlessbot'
# A stage node that died is started again after this long (ros2 launch's respawn_delay).
RESPAWN_DELAY_S = 2.0
# Who may discover the graph (ROS_AUTOMATIC_DISCOVERY_RANGE): this host only unless the launch
# argument, the cell file's ``discovery_range`` or the environment asks for more.
DISCOVERY_RANGES = ('LOCALHOST', 'SUBNET', 'SYSTEM_DEFAULT', 'OFF')
DISCOVERY_VARIABLE = 'ROS_AUTOMATIC_DISCOVERY_RANGE'
# How long the replay waits for the bag's subscribers after the graph is ready (s).
REPLAY_SUBSCRIBER_WAIT_S = 10


@dataclass(frozen=True)
class GraphProcess:
    """One process of the graph.

    ``executable`` is an executable of the package (``lib/tlessbot_ros/<executable>``): a node
    (module ``tlessbot_ros.nodes.<executable>``) or the ``tlessbot`` tool, which gets
    ``arguments``. A node (``is_node``) also gets the parameter file, then ``overrides``
    (name, value) in order, in ``namespace``. ``respawn``: started again when it dies, if the
    launcher respawns.
    """

    label: str
    executable: str
    arguments: tuple[str, ...] = ()
    namespace: str | None = None
    overrides: tuple[tuple[str, str], ...] = ()
    respawn: bool = False

    @property
    def is_node(self) -> bool:
        return self.executable != TOOL_EXECUTABLE


def string_parameter(value: str) -> str:
    """``value`` as a parameter value both rcl's ``-p NAME:=VALUE`` and launch read as a
    string: a leading ``_`` keeps a numeric serial a string (the camera driver strips it, as
    realsense-ros does)."""
    return '_' + value.lstrip('_')


def graph_description(*, replay: str | None = None, rate: float = 1.0, loop: bool = False,
                      nodes: list[str] | None = None, serials: dict[str, str] | None = None,
                      output_frame: str | None = None,
                      parts: str | None = None,
                      foxglove: bool = False) -> list[GraphProcess]:
    """The processes of the graph, in start order.

    Two camera drivers (namespaced per camera, ``serials[camera]`` selects the device; none =
    the first found) or, with ``replay`` (a bag), the replay tool instead. The replay waits
    until every stage node started here reports ready, then for the bag's subscribers.
    ``output_frame`` overrides the pose estimator's ('camera' or 'world'); None = the file's.
    ``parts`` (a parts folder) overrides the ``parts_path`` of the nodes that read it.
    ``foxglove`` adds the Foxglove live view.
    """
    wanted = list(nodes or NODE_EXECUTABLES)
    if foxglove and FOXGLOVE_NODE not in wanted:
        wanted.append(FOXGLOVE_NODE)
    known = (*NODE_EXECUTABLES, FOXGLOVE_NODE)
    unknown = [name for name in wanted if name not in known]
    if unknown:
        raise TlessbotError(f'node {unknown[0]!r} is not part of this installation; the nodes '
                            f'are {", ".join(known)}')
    if rate <= 0:
        raise TlessbotError(f'replay rate must be positive, got {rate}')
    unknown_cameras = sorted(set(serials or {}) - set(CAMERA_NAMES))
    if unknown_cameras:
        raise TlessbotError(f'no camera named {unknown_cameras[0]!r}; the cameras are '
                            f'{", ".join(CAMERA_NAMES)}')
    processes = []
    if replay is not None:
        processes.append(_replay_process(replay, rate, loop,
                                         [n for n in PERCEPTION_NODES if n in wanted]))
    for name in wanted:
        if name == CAMERA_DRIVER:
            if replay is None:
                processes += [_camera_driver(camera, (serials or {}).get(camera, ''))
                              for camera in CAMERA_NAMES]
        else:
            overrides = (('output_frame', output_frame),) \
                if name == 'pose_estimator' and output_frame else ()
            if parts and name in PARTS_NODES:
                overrides += (('parts_path', str(Path(parts).expanduser().resolve())),)
            processes.append(GraphProcess(name, name, overrides=overrides,
                                          respawn=name != FOXGLOVE_NODE))
    return processes


def _camera_driver(camera: str, serial: str) -> GraphProcess:
    overrides = [('camera_name', camera)]
    if serial:
        overrides.append(('serial_no', string_parameter(serial)))
    return GraphProcess(f'{CAMERA_DRIVER}/{camera}', CAMERA_DRIVER, namespace=f'/{camera}',
                        overrides=tuple(overrides))


def _replay_process(bag: str, rate: float, loop: bool, stages: list[str]) -> GraphProcess:
    arguments = ['replay', bag, '--rate', str(rate)]
    if stages:
        arguments += ['--wait-for-ready', *stages]
    arguments += ['--wait-for-subscribers', str(REPLAY_SUBSCRIBER_WAIT_S)]
    if loop:
        # Stamped now, as a camera stamps: unrestamped, every pass would send the bag's stamps
        # again, a jump back in time that each node takes for a clock step (and warns of).
        arguments += ['--loop', '--restamp']
    return GraphProcess('replay', TOOL_EXECUTABLE, arguments=tuple(arguments))


def discovery_range(*, argument: str | None, config_value: object = None,
                    environ: dict[str, str] | None = None) -> str:
    """The graph's ROS_AUTOMATIC_DISCOVERY_RANGE: the launch argument, else the cell file's
    ``discovery_range``, else the environment's, else 'LOCALHOST' (private to this host).

    Raises:
        TlessbotError: a value outside :data:`DISCOVERY_RANGES`.
    """
    for source, value in (('the launch argument', argument),
                          ('discovery_range in the cell file', config_value),
                          (DISCOVERY_VARIABLE, (environ or {}).get(DISCOVERY_VARIABLE))):
        if value:
            chosen = str(value).upper()
            if chosen not in DISCOVERY_RANGES:
                raise TlessbotError(f'{source} must be one of {", ".join(DISCOVERY_RANGES)} '
                                    f'(any case), got {value!r}')
            return chosen
    return 'LOCALHOST'
