"""tlessbot calibrate: the rig from a bag's depth, written into a copy of the cell YAML."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from tlessbot_ros.core.calibrate import rig_errors
from tlessbot_ros.core.common import CameraMount, Rig, look_at_params, rig_from_params
from tlessbot_ros.core.common import rotation_about_axis as turn
from tlessbot_ros.errors import TlessbotError
from tlessbot_ros.io.config import default_config_path, load_ros_params, package_path
from tlessbot_ros.tools.cli import main
from tlessbot_ros.tools.support.rig import load_rig, replace_rig_extrinsics, write_rig


def bumped(rig: Rig) -> Rig:
    """The side camera turned 12 deg about the vertical and tilted 4 deg, moved 4 cm; the top
    one tilted 3 deg and raised 2 cm."""
    cameras = dict(rig.cameras)
    for name, yaw, tilt, shift in (('side', 12.0, 4.0, (0.04, -0.01, 0.0)),
                                   ('top', 0.0, 3.0, (0.0, 0.0, 0.02))):
        T = rig[name].T_world_camera.copy()
        T[:3, :3] = turn([0, 0, 1], np.radians(yaw)) @ T[:3, :3] @ turn([1, 0, 0],
                                                                         np.radians(tilt))
        T[:3, 3] += shift
        cameras[name] = CameraMount(name, rig[name].intrinsics, T)
    return Rig(cameras=cameras)


def test_the_rig_is_written_in_place_of_the_old_values_whatever_their_style():
    rig = bumped(load_rig())
    flow = default_config_path().read_text()
    block = package_path('docs', 'bench', 'rig_moved_a.yaml').read_text()
    for text in (flow, block):
        written = replace_rig_extrinsics(text, rig, note='test')
        params = load_ros_params_text(written)
        for name in ('top', 'side'):
            np.testing.assert_allclose(rig_from_params(params)[name].T_world_camera,
                                       rig[name].T_world_camera, atol=1e-5)
        # every other line is kept
        old = [line for line in text.splitlines() if 'position_m' not in line]
        new = written.splitlines()
        assert [line for line in old if line.strip() and not line.strip().startswith('-')
                and line not in new and not line.strip().startswith(('look_at_m', 'up'))] == []
        assert written.count('# test') == 6
    with pytest.raises(TlessbotError, match='rig.side.position_m'):
        replace_rig_extrinsics(flow.replace('position_m: [0.0, -0.21838', 'where: [0.0'), rig)


def load_ros_params_text(text: str) -> dict:
    import tempfile

    with tempfile.NamedTemporaryFile('w', suffix='.yaml', delete=False) as f:
        f.write(text)
    try:
        return load_ros_params(f.name)
    finally:
        Path(f.name).unlink()


def test_look_at_params_round_trip_through_a_file(tmp_path):
    rig = bumped(load_rig())
    write_rig(default_config_path(), rig, tmp_path / 'cell.yaml')
    for name, (position, target, up) in ((n, look_at_params(rig[n].T_world_camera))
                                         for n in ('top', 'side')):
        params = load_ros_params(tmp_path / 'cell.yaml')
        np.testing.assert_allclose(params[f'rig.{name}.position_m'], position, atol=1e-6)
        np.testing.assert_allclose(params[f'rig.{name}.look_at_m'], target, atol=1e-6)
        np.testing.assert_allclose(params[f'rig.{name}.up'], up, atol=1e-6)


def test_calibrate_recovers_the_rig_of_the_demo_bag_from_a_wrong_config(tmp_path, capsys):
    truth = load_rig()                     # the demo bag was recorded with config/cell.yaml
    wrong = tmp_path / 'wrong.yaml'
    write_rig(default_config_path(), bumped(truth), wrong)
    out = tmp_path / 'calibrated.yaml'
    assert main(['calibrate', '--bag', str(package_path('bags', 'demo')), '--config', str(wrong),
                 '--out', str(out), '--truth', str(default_config_path())]) == 0
    printed = capsys.readouterr().out
    assert 'confident' in printed and f'wrote {out}' in printed
    # the config's own errors, as --truth prints them: what the bump did
    line = next(line for line in printed.splitlines() if line.startswith('  top -> side    '))
    assert float(line.split('|')[1].split()[0]) == pytest.approx(
        rig_errors(truth, bumped(truth)).relative.angle_deg, abs=1e-3)
    calibrated = rig_from_params(load_ros_params(out))
    errors = rig_errors(truth, calibrated)
    assert errors.relative.angle_deg < 0.5 and errors.relative.offset_m < 0.005, errors
    for name in ('top', 'side'):
        assert abs(errors.height_m[name]) < 0.002 and errors.tilt_deg[name] < 0.2, errors
    # the rest of the file is the --config file's
    kept = [line for line in wrong.read_text().splitlines()
            if not line.strip().startswith(('position_m', 'look_at_m', 'up'))]
    assert kept == [line for line in out.read_text().splitlines()
                    if not line.strip().startswith(('position_m', 'look_at_m', 'up'))]


def test_calibrate_on_a_simulated_bag_with_a_bumped_rig(tmp_path, tless_models_dir, capsys):
    truth = bumped(load_rig())
    config = tmp_path / 'bumped.yaml'
    write_rig(default_config_path(), truth, config)
    bag = tmp_path / 'bag'
    assert main(['simulate', '--models', str(tless_models_dir), '--bag', str(bag), '--frames',
                 '4', '--seed', '23', '--parts-min', '3', '--parts-max', '5', '--ids', '2', '5',
                 '11', '19', '23', '25', '--config', str(config), '--no-progress',
                 '--cloud-stride', '8']) == 0
    out = tmp_path / 'calibrated.yaml'
    assert main(['calibrate', '--bag', str(bag), '--out', str(out)]) == 0   # from cell.yaml
    errors = rig_errors(truth, load_rig(out))
    assert errors.relative.angle_deg < 0.5 and errors.relative.offset_m < 0.005, errors
    for name in ('top', 'side'):
        assert abs(errors.height_m[name]) < 0.002 and errors.tilt_deg[name] < 0.2, errors


def test_calibrate_errors_are_one_line(tmp_path, capsys):
    assert main(['calibrate', '--bag', str(tmp_path / 'missing'), '--out',
                 str(tmp_path / 'x.yaml')]) == 1
    assert 'bag not found' in capsys.readouterr().err
    assert main(['calibrate', '--board', '--out', str(tmp_path / 'x.yaml')]) == 1
    assert '--board' in capsys.readouterr().err
    assert not (tmp_path / 'x.yaml').exists()


@pytest.mark.ros
def test_calibrate_live_from_the_camera_topics(tmp_path):
    import sys

    from running import Running

    from tlessbot_ros.conversions.topics import DEPTH, DEPTH_INFO, camera_topic

    cli = [sys.executable, '-m', 'tlessbot_ros.tools.cli']
    wrong = tmp_path / 'wrong.yaml'
    write_rig(default_config_path(), bumped(load_rig()), wrong)
    out = tmp_path / 'live.yaml'
    calibrate = Running([*cli, 'calibrate', '--live', '--frames', '6', '--timeout', '120',
                         '--config', str(wrong), '--out', str(out)])
    topics = [camera_topic(c, t) for c in ('top', 'side') for t in (DEPTH, DEPTH_INFO)]
    replay = Running([*cli, 'replay', str(package_path('bags', 'demo')), '--loop', '--restamp',
                      '--rate', '0.5', '--topics', *topics])
    try:
        assert calibrate.wait(timeout_s=180.0) == 0, calibrate.output
    finally:
        replay.kill()
        calibrate.kill()
    assert f'wrote {out}' in calibrate.output
    errors = rig_errors(load_rig(), load_rig(out))
    assert errors.relative.angle_deg < 0.5 and errors.relative.offset_m < 0.005, errors
