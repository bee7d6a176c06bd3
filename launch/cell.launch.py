"""One cell's perception graph: ``ros2 launch tlessbot_ros cell.launch.py [NAME:=VALUE ...]``.

    ros2 launch tlessbot_ros cell.launch.py top_serial:=123456789 side_serial:=987654321
    ros2 launch tlessbot_ros cell.launch.py replay:=/path/to/bag rate:=0.5 loop:=true
    ros2 launch tlessbot_ros cell.launch.py config:=/path/to/my_cell.yaml output_frame:=world
    ros2 launch tlessbot_ros cell.launch.py parts:=/path/to/my_parts   # tlessbot parts build

It starts the processes ``tlessbot launch`` starts, from the same description
(tlessbot_ros/tools/support/cell_graph.py): two camera drivers in /top and /side, or with
``replay:=BAG`` the bag replay instead (it waits until the stage nodes are ready), then the
localiser, classifier and pose estimator. Every node reads ``config`` first; the stage nodes
are started again ``RESPAWN_DELAY_S`` after they die unless ``respawn:=false``.
``ros2 launch tlessbot_ros cell.launch.py --show-args`` lists the arguments.
"""
import os
from pathlib import Path

from launch import LaunchDescription
from launch.actions import (
    DeclareLaunchArgument,
    ExecuteProcess,
    OpaqueFunction,
    SetEnvironmentVariable,
)
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution
from launch_ros.actions import Node
from launch_ros.parameter_descriptions import ParameterValue
from launch_ros.substitutions import ExecutableInPackage, FindPackageShare

from tlessbot_ros.core.common.rig import CAMERA_NAMES
from tlessbot_ros.errors import TlessbotError
from tlessbot_ros.io.config import load_ros_params
from tlessbot_ros.io.parts import open_parts_folder
from tlessbot_ros.tools.support.cell_graph import (
    DISCOVERY_VARIABLE,
    RESPAWN_DELAY_S,
    discovery_range,
    graph_description,
)
from tlessbot_ros.tools.support.rig import load_rig

PACKAGE = 'tlessbot_ros'
BOOLEANS = {'true': True, '1': True, 'false': False, '0': False}


def launch_arguments() -> list[DeclareLaunchArgument]:
    serials = [DeclareLaunchArgument(
        f'{camera}_serial', default_value='',
        description=f'serial number of the {camera} camera (empty: any device)')
        for camera in CAMERA_NAMES]
    return [
        DeclareLaunchArgument(
            'config', default_value=PathJoinSubstitution(
                [FindPackageShare(PACKAGE), 'config', 'cell.yaml']),
            description='parameter YAML of every node'),
        *serials,
        DeclareLaunchArgument('parts', default_value='',
                              description="parts folder of tlessbot parts build (empty: the "
                                          "config's parts_path, else the packaged T-LESS parts)"),
        DeclareLaunchArgument('replay', default_value='',
                              description='replay this bag instead of starting the cameras'),
        DeclareLaunchArgument('rate', default_value='1.0', description='replay rate'),
        DeclareLaunchArgument('loop', default_value='false', choices=['true', 'false'],
                              description='replay the bag in a loop, stamped now'),
        DeclareLaunchArgument('output_frame', default_value='', choices=['', 'camera', 'world'],
                              description="frame of the poses (empty: the config file's)"),
        DeclareLaunchArgument('respawn', default_value='true', choices=['true', 'false'],
                              description='start a stage node again when it dies'),
        DeclareLaunchArgument('foxglove', default_value='false', choices=['true', 'false'],
                              description='also start the Foxglove live view '
                                          '(foxglove_view, ws://127.0.0.1:8765)'),
        DeclareLaunchArgument('discovery_range', default_value='',
                              description="ROS_AUTOMATIC_DISCOVERY_RANGE of the graph: LOCALHOST "
                                          "(private), SUBNET (two PCs); empty: the config's "
                                          "discovery_range, else LOCALHOST"),
    ]


def graph_actions(context) -> list:
    """The graph's Node / ExecuteProcess actions for the launch arguments in ``context``."""
    def argument(name: str) -> str:
        return LaunchConfiguration(name).perform(context)

    config = argument('config')
    if not Path(config).is_file():
        raise TlessbotError(f'parameter file not found: {config}')
    if argument('parts'):   # refused in one line before any node starts
        open_parts_folder(argument('parts'), rig=load_rig(Path(config)))
    try:
        rate = float(argument('rate'))
    except ValueError:
        raise TlessbotError(f'rate must be a number, got {argument("rate")!r}') from None
    description = graph_description(
        replay=argument('replay') or None, rate=rate, loop=BOOLEANS[argument('loop')],
        serials={camera: argument(f'{camera}_serial') for camera in CAMERA_NAMES},
        output_frame=argument('output_frame') or None, parts=argument('parts') or None,
        foxglove=BOOLEANS[argument('foxglove')])
    respawn = BOOLEANS[argument('respawn')]
    scope = discovery_range(argument=argument('discovery_range'),
                            config_value=load_ros_params(config).get('discovery_range'),
                            environ=dict(os.environ))
    return [SetEnvironmentVariable(DISCOVERY_VARIABLE, scope),
            *[_action(process, config, respawn) for process in description]]


def _action(process, config: str, respawn: bool):
    if not process.is_node:
        return ExecuteProcess(
            cmd=[ExecutableInPackage(process.executable, PACKAGE), *process.arguments],
            name=process.label, output='screen')
    overrides = {name: ParameterValue(value, value_type=str) for name, value in process.overrides}
    return Node(package=PACKAGE, executable=process.executable, namespace=process.namespace,
                parameters=[config, overrides] if overrides else [config], output='screen',
                respawn=respawn and process.respawn, respawn_delay=RESPAWN_DELAY_S)


def generate_launch_description() -> LaunchDescription:
    return LaunchDescription([*launch_arguments(), OpaqueFunction(function=graph_actions)])
