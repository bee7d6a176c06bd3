"""tlessbot approve / check without the graph: cells' bags (realsense-ros names, ros2 bag record
log times, sqlite3 and mcap), the expected-poses file, JUnit XML, exit 2 on a broken set-up."""

import junitparser
import numpy as np
import pytest
from cell_bags import CAMERA_TOPICS, cell_bag
from rosbags.rosbag2 import StoragePlugin

from tlessbot_ros.conversions.cdr import header_stamp_ns
from tlessbot_ros.core.common import make_transform
from tlessbot_ros.core.regression import PartPose, check_frames
from tlessbot_ros.io.bags import read_bag
from tlessbot_ros.tools.cli import main
from tlessbot_ros.tools.commands.check import format_table
from tlessbot_ros.tools.support.bag_inputs import (
    SetupError,
    find_cameras,
    replay_cameras,
    stage_bag,
)
from tlessbot_ros.tools.support.defaults import DEFAULT_BAG
from tlessbot_ros.tools.support.expected_poses import (
    ApprovedRun,
    ExpectedFileError,
    read_expected,
    write_expected,
)
from tlessbot_ros.tools.support.junit import write_junit

pytestmark = pytest.mark.rosbag
def test_find_cameras_under_realsense_names():
    names = [f'{p}/{t}' for p in ('/cell/top', '/cell/side') for t in CAMERA_TOPICS]
    assert find_cameras(names, ['top', 'side']) == {'top': '/cell/top', 'side': '/cell/side'}
    names = [f'{p}/{t}' for p in ('/top/top', '/camera/camera') for t in CAMERA_TOPICS]
    assert find_cameras(names, ['top', 'side'], {'side': '/camera/camera'}) == \
        {'top': '/top/top', 'side': '/camera/camera'}
    # one camera, realsense-ros's default namespace: a rig of that one camera, named after it
    one = [f'/camera/camera/{t}' for t in CAMERA_TOPICS]
    assert find_cameras(one, ['top', 'side'], bag='run1') == {'camera': '/camera/camera'}
    assert find_cameras(one, ['top', 'side'], {'side': '/camera/camera'}) == \
        {'side': '/camera/camera'}
    assert find_cameras(one, ['top', 'side'], {'front': '/camera/camera'}) == \
        {'front': '/camera/camera'}
    # one of the rig's cameras alone: a rig of that camera
    side = [f'/cell/side/{t}' for t in CAMERA_TOPICS]
    assert find_cameras(side, ['top', 'side']) == {'side': '/cell/side'}
    # a rig camera missing while the bag has another camera's topics: which is which is not
    # clear; the line names what is missing and how to map the camera there is
    with pytest.raises(SetupError) as error:
        find_cameras(side + one, ['top', 'side'], bag='run1')
    message = str(error.value)
    assert '\n' not in message
    assert 'run1 lacks the topics of camera(s) top' in message
    assert '/top/aligned_depth_to_color/image_raw' in message
    assert '--camera top=/camera/camera' in message
    with pytest.raises(SetupError, match='lacks the topics of camera'):
        find_cameras(['/cell/a/color/image_raw', '/cell/b/color/image_raw'], ['top', 'side'])
    with pytest.raises(SetupError, match='or one --camera NAME=PREFIX alone'):
        find_cameras(one, ['top', 'side'], {'a': '/camera/camera', 'b': '/x'})
    with pytest.raises(SetupError, match='two cameras to one prefix'):
        find_cameras(one, ['top', 'side'], {'top': '/camera/camera', 'side': '/camera/camera'})
    with pytest.raises(SetupError, match='lacks /camera/camera/aligned_depth_to_color/image_raw'
                       r'.*\(the stages need the aligned depth'):
        find_cameras([f'/camera/camera/{t}' for t in CAMERA_TOPICS[:2]], ['side'],
                     {'side': '/camera/camera'})


@pytest.mark.parametrize('storage', [StoragePlugin.SQLITE3, StoragePlugin.MCAP])
def test_a_recorded_bag_is_staged_as_whole_frames(tmp_path, storage):
    bag = cell_bag(tmp_path / 'rec', {'top': '/top/top', 'side': '/camera/camera'},
                   storage=storage)
    staged = stage_bag(bag, tmp_path / 'staged', {'top': '/top/top', 'side': '/camera/camera'})
    assert len(staged.frames) == 3 and staged.skipped == 0
    messages = list(read_bag(staged.path))
    assert {m.topic for m in messages} == {f'/{c}/{t}' for c in ('top', 'side')
                                           for t in CAMERA_TOPICS}
    # one log time per frame, the side colour stamp, every message of the frame under it
    assert sorted({m.log_time_ns for m in messages}) == staged.frames
    for message in messages:
        assert header_stamp_ns(message.raw) == message.log_time_ns
    assert len(messages) == 3 * 8
    source = {header_stamp_ns(m.raw): m.raw for m in read_bag(bag, ['/top/top/color/image_raw'])}
    staged_top = [m for m in messages if m.topic == '/top/color/image_raw']
    assert all(source[m.log_time_ns] == m.raw for m in staged_top)   # bytes kept as recorded


def test_a_bag_of_one_camera_is_staged_under_its_own_stamps(tmp_path):
    bag = cell_bag(tmp_path / 'rec', {'side': '/camera/camera'})
    staged = stage_bag(bag, tmp_path / 'staged', {'front': '/camera/camera'})
    assert len(staged.frames) == 3 and staged.skipped == 0
    messages = list(read_bag(staged.path))
    assert {m.topic for m in messages} == {f'/front/{t}' for t in CAMERA_TOPICS}
    assert sorted({m.log_time_ns for m in messages}) == staged.frames
    assert all(header_stamp_ns(m.raw) == m.log_time_ns for m in messages)


def test_a_plain_replay_of_one_camera_runs_the_graph_with_that_camera(tmp_path):
    assert replay_cameras(cell_bag(tmp_path / 'side', {'side': '/side'}),
                          ['top', 'side']) == ['side']
    # the graph's own names only: a plain replay does not rename topics
    assert replay_cameras(cell_bag(tmp_path / 'rs', {'side': '/camera/camera'}),
                          ['top', 'side']) is None
    assert replay_cameras(DEFAULT_BAG, ['top', 'side']) is None


def test_a_frame_missing_a_message_is_left_out(tmp_path):
    cameras = {'top': '/top', 'side': '/side'}
    bag = cell_bag(tmp_path / 'rec', cameras, drop=('top/aligned_depth_to_color/camera_info@1',))
    staged = stage_bag(bag, tmp_path / 'staged', cameras)
    assert staged.skipped == 1 and len(staged.frames) == 2
    assert sorted({m.log_time_ns for m in read_bag(staged.path)}) == staged.frames
    with pytest.raises(SetupError, match='no whole frame'):
        stage_bag(cell_bag(tmp_path / 'none', cameras,
                           drop=('top/aligned_depth_to_color/camera_info',)),
                  tmp_path / 'x', cameras)


def test_check_exits_2_with_one_line_on_a_broken_set_up(tmp_path, capsys):
    expected = tmp_path / 'expected.yaml'
    write_expected(expected, ApprovedRun({1: []}, {'bag': 'x'}))
    no_depth = cell_bag(tmp_path / 'nodepth', {'top': '/top', 'side': '/side'},
                        drop=('top/aligned_depth_to_color/image_raw',
                              'side/aligned_depth_to_color/image_raw'))
    cases = [
        ([str(no_depth)], 'lacks /top/aligned_depth_to_color/image_raw, '
                          '/side/aligned_depth_to_color/image_raw (the stages need the aligned '
                          'depth (realsense-ros align_depth.enable:=true))'),
        ([str(tmp_path / 'none')], 'bag not found'),
        ([str(DEFAULT_BAG), '--templates', str(tmp_path / 'none.npz')], 'model file not found'),
    ]
    for argv, reason in cases:
        assert main(['check', *argv, '--expected', str(expected)]) == 2
        err = capsys.readouterr().err
        assert reason in err and err.count('\n') == 1, err
    (tmp_path / 'bad.yaml').write_text('format: something-else\n')
    assert main(['check', str(DEFAULT_BAG), '--expected', str(tmp_path / 'bad.yaml')]) == 2
    assert 'is not a tlessbot-expected-poses file' in capsys.readouterr().err
    assert main(['approve', str(no_depth), '--out', str(tmp_path / 'e.yaml')]) == 2
    assert 'lacks /top/aligned_depth_to_color/image_raw' in capsys.readouterr().err
    assert not (tmp_path / 'e.yaml').exists()


def test_expected_file_round_trip_and_junit_read_by_junitparser(tmp_path):
    R = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    parts = [PartPose('obj_05', make_transform(R, [0.1, -0.02, 0.6]), 'side_color_optical_frame',
                      0.93), PartPose('obj_06', np.eye(4), 'world', None)]
    path = tmp_path / 'expected.yaml'
    write_expected(path, ApprovedRun({20: parts, 10: []}, {'bag': 'b', 'replay': 'lockstep'}))
    back = read_expected(path)
    assert sorted(back.frames) == [10, 20] and back.info['replay'] == 'lockstep'
    assert [p.name for p in back.frames[20]] == ['obj_05', 'obj_06']
    assert np.allclose(back.frames[20][0].T, parts[0].T, atol=1e-6)
    assert back.frames[20][0].score == 0.93 and back.frames[20][1].score is None
    with pytest.raises(ExpectedFileError, match='not found'):
        read_expected(tmp_path / 'none.yaml')

    moved = PartPose('obj_05', make_transform(R, [0.1, -0.01, 0.6]), parts[0].frame_id, 0.9)
    checks = check_frames(back.frames, {10: [], 20: [moved, parts[1]]}, {})
    table = format_table(checks, {10: 0, 20: 1})
    assert 'obj_05  MOVED   10.00' in table and 'obj_06  ok' in table
    xml = tmp_path / 'report.xml'
    write_junit(xml, checks, suite='tlessbot check b', frame_index={10: 0, 20: 1})
    suites = junitparser.JUnitXml.fromfile(str(xml))
    (suite,) = list(suites)
    cases = list(suite)
    assert (suite.tests, suite.failures) == (2, 1)
    failed = [c for c in cases if not c.is_passed]
    assert [c.name for c in failed] == ['frame 001 (stamp 20) obj_05']
    (result,) = failed[0].result
    assert isinstance(result, junitparser.Failure) and result.type == 'moved'
    assert result.message == 'moved: 10.00 mm, 0.00 deg'


def test_the_ci_recipe_parses_and_uses_real_options():
    import argparse
    import re
    from pathlib import Path

    import yaml

    from tlessbot_ros.tools.commands import approve, check

    text = (Path(__file__).resolve().parents[2] / 'docs' / 'ci.md').read_text()
    (block,) = re.findall(r'```yaml\n(.*?)```', text, re.S)
    workflow = yaml.safe_load(block)
    assert set(workflow['jobs']) == {'standalone', 'colcon'}
    colcon = ' '.join(s.get('run', '') for s in workflow['jobs']['colcon']['steps'])
    assert 'colcon build' in colcon and 'ros2 run tlessbot_ros tlessbot check' in colcon
    for module, command in ((check, 'check'), (approve, 'approve')):
        parser = argparse.ArgumentParser()
        module.add_arguments(parser)
        known = {o for action in parser._actions for o in action.option_strings}
        used = set(re.findall(rf'tlessbot {command} [^\n]*(?:\\\n[^\n]*)*', text))
        assert used
        for line in used:
            assert set(re.findall(r'(?<=\s)--[a-z-]+', line)) <= known, line


def test_a_graph_that_fails_to_start_is_told_in_one_line():
    from tlessbot_ros.tools.support.approval_run import one_line

    # the shape of run_graph_on_bag's error: a first line, then the nodes' last output
    message = ('pose_estimator exited with code 1 during start-up:\n[INFO] [localiser]: ready\n'
               "[pose_estimator] PoseEstimatorNode: error: output_frame must be 'camera' or "
               "'world', got 'bogus'\n\n")
    assert one_line(message) == (
        'pose_estimator exited with code 1 during start-up: [pose_estimator] PoseEstimatorNode: '
        "error: output_frame must be 'camera' or 'world', got 'bogus'")
    assert one_line('the perception nodes did not come up within 3 s:\n') == \
        'the perception nodes did not come up within 3 s'
