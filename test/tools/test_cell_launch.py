"""launch/cell.launch.py starts what `tlessbot launch` starts: the same executables, namespaces,
parameter file and overrides, compared on the command lines launch would run (nothing runs)."""
import importlib.util
import shutil
from pathlib import Path

import pytest
import yaml
from ros2_tools import needs_ros2

from tlessbot_ros.errors import TlessbotError
from tlessbot_ros.io.config import default_config_path
from tlessbot_ros.tools.support.cell_graph import NODE_EXECUTABLES, TOOL_EXECUTABLE
from tlessbot_ros.tools.support.processes import graph_processes

pytestmark = [needs_ros2]

LAUNCH_FILE = Path(__file__).resolve().parents[2] / 'launch' / 'cell.launch.py'


@pytest.fixture
def installed_prefix(tmp_path, monkeypatch):
    """A stand-in colcon install of the package (ament index entry, lib/ executables, share/
    config), so the launch file's package lookups resolve without building."""
    (tmp_path / 'share' / 'ament_index' / 'resource_index' / 'packages').mkdir(parents=True)
    (tmp_path / 'share' / 'ament_index' / 'resource_index' / 'packages' / 'tlessbot_ros').touch()
    (tmp_path / 'share' / 'tlessbot_ros' / 'config').mkdir(parents=True)
    shutil.copy(default_config_path(), tmp_path / 'share' / 'tlessbot_ros' / 'config')
    lib = tmp_path / 'lib' / 'tlessbot_ros'
    lib.mkdir(parents=True)
    for name in (*NODE_EXECUTABLES, TOOL_EXECUTABLE):
        (lib / name).write_text('#!/bin/sh\n')
        (lib / name).chmod(0o755)
    monkeypatch.setenv('AMENT_PREFIX_PATH', str(tmp_path))
    return tmp_path


def launched_commands(arguments: dict[str, str]) -> list[list[str]]:
    """The command line of every process the launch file starts with ``arguments``."""
    from launch import LaunchContext
    from launch.actions import DeclareLaunchArgument, OpaqueFunction
    from launch.utilities import perform_substitutions
    from launch_ros.actions import Node

    spec = importlib.util.spec_from_file_location('cell_launch', LAUNCH_FILE)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    context = LaunchContext()
    context.launch_configurations.update(arguments)
    entities = module.generate_launch_description().entities
    for declaration in entities:
        if isinstance(declaration, DeclareLaunchArgument):
            declaration.execute(context)   # applies defaults, checks choices
    opaque = [e for e in entities if isinstance(e, OpaqueFunction)]
    assert len(opaque) == 1
    commands = []
    for action in opaque[0].execute(context):
        if not hasattr(action, 'cmd'):   # SetEnvironmentVariable (the discovery range)
            continue
        if isinstance(action, Node):
            action._perform_substitutions(context)   # what Node.execute does first
            context.extend_locals({'ros_specific_arguments': {
                'ns': f'__ns:={action.expanded_node_namespace}'}})
        commands.append([perform_substitutions(context, part) for part in action.cmd])
    return commands


def node_invocation(executable: str, ros_args: list[str]) -> tuple:
    """(executable, namespace, parameter files, overrides) from a node's ROS arguments; a
    parameter file launch wrote for a dict of parameters counts as overrides."""
    namespace, files, overrides = None, [], {}
    tokens = iter(a for a in ros_args if a != '--ros-args')
    for token in tokens:
        value = next(tokens)
        if token == '--params-file' and Path(value).name.startswith('launch_params_'):
            document = yaml.safe_load(Path(value).read_text())
            overrides.update(document['/**']['ros__parameters'])
        elif token == '--params-file':
            files.append(value)
        elif token == '-r' and value.startswith('__ns:='):
            namespace = value.split(':=', 1)[1]
        elif token == '-p':
            name, text = value.split(':=', 1)
            overrides[name] = yaml.safe_load(text)   # rcl reads -p values as YAML
        else:
            raise AssertionError(f'unexpected ROS argument {token} {value}')
    return executable, namespace, files, overrides


def from_launch(command: list[str]) -> tuple:
    if Path(command[0]).name == TOOL_EXECUTABLE:
        return ('tool', command[1:])
    return node_invocation(Path(command[0]).name, command[1:])


def from_tlessbot_launch(argv: list[str]) -> tuple:
    module = argv[2]   # python -m MODULE ...
    if module == 'tlessbot_ros.tools.cli':
        return ('tool', argv[3:])
    return node_invocation(module.rsplit('.', 1)[1], argv[3:])


def test_cameras_and_stages_match_tlessbot_launch(installed_prefix, tmp_path):
    config = tmp_path / 'my_cell.yaml'
    shutil.copy(default_config_path(), config)
    launched = launched_commands({'config': str(config), 'top_serial': '123456789',
                                  'side_serial': '_987654321', 'output_frame': 'world'})
    specs = graph_processes(config, serials={'top': '123456789', 'side': '_987654321'},
                            output_frame='world')
    assert [from_launch(c) for c in launched] == [from_tlessbot_launch(s.argv) for s in specs]
    top = from_launch(launched[0])
    # Serials stay strings (a number would not match the driver's string parameter).
    assert top == ('camera_driver', '/top', [str(config)],
                   {'camera_name': 'top', 'serial_no': '_123456789'})
    assert from_launch(launched[-2])[3] == {'output_frame': 'world'}   # pose_estimator


def test_replay_matches_tlessbot_launch_and_defaults_to_the_installed_config(installed_prefix):
    bag = str(Path(__file__).resolve().parents[2] / 'bags' / 'demo')
    launched = launched_commands({'replay': bag, 'rate': '0.5', 'loop': 'true'})
    installed_config = installed_prefix / 'share' / 'tlessbot_ros' / 'config' / 'cell.yaml'
    specs = graph_processes(installed_config, replay=bag, rate=0.5, loop=True)
    assert [from_launch(c) for c in launched] == [from_tlessbot_launch(s.argv) for s in specs]
    assert [from_launch(c)[0] for c in launched] == \
        ['tool', 'localiser', 'classifier', 'pose_estimator', 'objects']
    replay = from_launch(launched[0])[1]
    assert replay[:2] == ['replay', bag]
    assert replay[replay.index('--wait-for-ready') + 1:][:3] == \
        ['localiser', 'classifier', 'pose_estimator']
    assert all(from_launch(c)[2] == [str(installed_config)] for c in launched[1:])


@pytest.mark.parametrize(('arguments', 'message'), [
    ({'config': '/nonexistent.yaml'}, 'parameter file not found: /nonexistent.yaml'),
    ({'rate': 'fast'}, "rate must be a number, got 'fast'"),
    ({'replay': 'bag', 'rate': '0'}, 'replay rate must be positive, got 0.0'),
])
def test_bad_arguments_are_one_line_errors(installed_prefix, arguments, message):
    with pytest.raises(TlessbotError) as error:
        launched_commands(arguments)
    assert str(error.value) == message



def test_launch_keeps_the_graph_on_this_host_unless_asked(installed_prefix, monkeypatch):
    from launch import LaunchContext
    from launch.actions import SetEnvironmentVariable

    monkeypatch.delenv('ROS_AUTOMATIC_DISCOVERY_RANGE', raising=False)
    spec = importlib.util.spec_from_file_location('cell_launch_scope', LAUNCH_FILE)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    for argument, expected in (('', 'LOCALHOST'), ('subnet', 'SUBNET')):
        context = LaunchContext()
        for action in module.launch_arguments():
            action.execute(context)
        context.launch_configurations['discovery_range'] = argument
        actions = module.graph_actions(context)
        scope = [a for a in actions if isinstance(a, SetEnvironmentVariable)]
        assert len(scope) == 1
        scope[0].visit(context)
        assert context.environment['ROS_AUTOMATIC_DISCOVERY_RANGE'] == expected
