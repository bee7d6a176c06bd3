"""The cell graph's description and its argvs for `tlessbot launch` (pure)."""
from pathlib import Path

import pytest

from tlessbot_ros.errors import TlessbotError
from tlessbot_ros.tools.support.cell_graph import graph_description
from tlessbot_ros.tools.support.processes import graph_processes


def test_serials_and_output_frame_become_overrides_after_the_parameter_file():
    specs = graph_processes(Path('cell.yaml'), serials={'side': '987654321'},
                            output_frame='world', extra_ros_args=['-p', 'a:=1'])
    by_label = {s.label: s.argv for s in specs}
    side, top = by_label['camera_driver/side'], by_label['camera_driver/top']
    # A leading _ keeps a numeric serial a string for rcl (the driver strips it).
    assert side[side.index('--ros-args'):] == [
        '--ros-args', '--params-file', 'cell.yaml', '-p', 'a:=1', '-r', '__ns:=/side',
        '-p', 'camera_name:=side', '-p', 'serial_no:=_987654321']
    assert not any(a.startswith('serial_no') for a in top)
    assert by_label['pose_estimator'][-2:] == ['-p', 'output_frame:=world']
    assert not any(a.startswith('output_frame') for a in by_label['localiser'])


def test_the_replay_waits_for_the_stage_nodes_it_is_started_with():
    specs = graph_processes(Path('cell.yaml'), replay='bag', nodes=['localiser', 'classifier'])
    replay = specs[0].argv
    assert replay[replay.index('--wait-for-ready') + 1:][:3] == \
        ['localiser', 'classifier', '--wait-for-subscribers']


def test_only_stage_nodes_respawn():
    respawning = {p.label for p in graph_description() if p.respawn}
    assert respawning == {'localiser', 'classifier', 'pose_estimator', 'objects'}


@pytest.mark.parametrize(('kwargs', 'message'), [
    ({'serials': {'front': '1'}}, "no camera named 'front'"),
    ({'replay': 'bag', 'rate': -1.0}, 'replay rate must be positive'),
])
def test_bad_descriptions_are_errors(kwargs, message):
    with pytest.raises(TlessbotError, match=message):
        graph_description(**kwargs)


def test_discovery_range_is_private_unless_asked():
    from tlessbot_ros.tools.support.cell_graph import discovery_range
    assert discovery_range(argument=None) == 'LOCALHOST'
    assert discovery_range(argument='', config_value='subnet') == 'SUBNET'
    assert discovery_range(argument='localhost', config_value='SUBNET') == 'LOCALHOST'
    assert discovery_range(argument=None, environ={'ROS_AUTOMATIC_DISCOVERY_RANGE': 'SUBNET'}) \
        == 'SUBNET'
    with pytest.raises(TlessbotError, match='discovery_range in the cell file'):
        discovery_range(argument=None, config_value='everywhere')


def test_foxglove_view_only_when_asked():
    assert 'foxglove_view' not in {p.label for p in graph_description()}
    view = [p for p in graph_description(foxglove=True) if p.label == 'foxglove_view']
    assert len(view) == 1 and not view[0].respawn
