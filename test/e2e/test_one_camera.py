"""A cell of one camera, end to end over the real graph: a simulated bag of the side camera alone
(tlessbot simulate --cameras side, 3 frames) is approved and checked unchanged (exit 0), the
graph running with ``rig.cameras: [side]`` (two graph runs); a check against poses approved
with two cameras is a broken set-up (exit 2, no graph started)."""
import json

import pytest

from tlessbot_ros.tools.cli import main
from tlessbot_ros.tools.support.expected_poses import ApprovedRun, read_expected, write_expected

pytestmark = [pytest.mark.ros, pytest.mark.rosbag, pytest.mark.slow]


@pytest.fixture(scope='module')
def side_bag(tmp_path_factory, tless_models_dir):
    bag = tmp_path_factory.mktemp('one_camera') / 'side_only'
    assert main(['simulate', '--models', str(tless_models_dir), '--bag', str(bag), '--frames',
                 '3', '--seed', '4343', '--parts-min', '3', '--parts-max', '6',
                 '--cloud-stride', '4', '--cameras', 'side', '--no-progress']) == 0
    return bag


def test_a_bag_of_one_camera_is_approved_then_checked(side_bag, tmp_path, capsys):
    expected = tmp_path / 'expected.yaml'
    assert main(['approve', str(side_bag), '--out', str(expected)]) == 0
    run = read_expected(expected)
    assert run.info['cameras'] == {'side': '/side'} and len(run.frames) == 3
    parts = [p for ps in run.frames.values() for p in ps]
    assert len(parts) >= 6 and {p.frame_id for p in parts} == {'side_color_optical_frame'}
    assert all(p.score is not None and 0.5 < p.score <= 1.0 for p in parts)
    assert len(list(tmp_path.glob('expected_overlays/frame_*.png'))) == 3
    capsys.readouterr()
    assert main(['check', str(side_bag), '--expected', str(expected)]) == 0
    out = capsys.readouterr().out
    assert f'check: all {len(parts)} parts match in 3 frames' in out, out


def test_poses_approved_with_two_cameras_do_not_check_a_bag_of_one(side_bag, tmp_path, capsys):
    expected = tmp_path / 'two.yaml'
    write_expected(expected, ApprovedRun({}, {'cameras': {'top': '/top', 'side': '/side'}}))
    assert main(['check', str(side_bag), '--expected', str(expected)]) == 2
    err = capsys.readouterr().err.strip()
    assert err == ('tlessbot check: error: the poses were approved with the cameras top, side, '
                   'but the bag has side (/side)')


def test_evaluate_scores_a_bag_of_one_camera_in_that_camera(side_bag, tless_models_dir,
                                                            tmp_path):
    out = tmp_path / 'evaluate'
    assert main(['evaluate', '--models', str(tless_models_dir), '--bag', str(side_bag),
                 '--out', str(out)]) == 0
    report = json.loads((out / 'report.json').read_text())
    assert report['split'] == 'bag (side camera)' and report['frames'] == 3, report
    assert report['objects_gt'] >= 9 and report['pose']['recall_5cm5deg'] > 0.5, report
