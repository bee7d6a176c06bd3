"""tlessbot calibrate --board on simulated bags, and tlessbot board."""
import cv2
import numpy as np
import yaml

from tlessbot_ros.core.calibrate import BoardSpec, detect_board
from tlessbot_ros.core.common import rotation_angle_deg
from tlessbot_ros.io.config import default_config_path
from tlessbot_ros.tools.cli import main
from tlessbot_ros.tools.support.rig import load_rig


def _moved_config(path):
    config = yaml.safe_load(default_config_path().read_text())
    rig = config['/**']['ros__parameters']['rig']
    rig['top']['position_m'], rig['top']['look_at_m'] = [0.03, -0.02, 1.12], [0.05, 0.06, 0.0]
    rig['side']['position_m'], rig['side']['look_at_m'] = [0.05, -0.25, 0.58], [-0.03, 0.01, 0.0]
    rig['side']['up'] = [0.1, 0.0, 1.0]  # rolled about 6 degrees
    path.write_text(yaml.safe_dump(config, sort_keys=False))
    return path


def _simulate(models, config, bag, *extra):
    assert main(['simulate', '--models', str(models), '--ids', '5', '--bag', str(bag),
                 '--frames', '2', '--seed', '21', '--config', str(config), '--parts-min', '0',
                 '--parts-max', '0', '--cloud-stride', '8', '--no-progress', *extra]) == 0


def test_calibrate_board_recovers_a_moved_rig(tmp_path, tless_models_dir, capsys):
    truth = _moved_config(tmp_path / 'moved.yaml')
    bag = tmp_path / 'bag'
    _simulate(tless_models_dir, truth, bag, '--board', '--board-pose', '0.02', '-0.01', '8')
    capsys.readouterr()
    out = tmp_path / 'measured.yaml'
    assert main(['calibrate', '--board', '--bag', str(bag), '--out', str(out),
                 '--board-pose', '0.02', '-0.01', '8']) == 0
    text = capsys.readouterr().out
    assert 'top: 2 of 2 images fitted together' in text
    assert 'the prior rig is' in text and f'wrote {out}' in text
    measured, expected = load_rig(out), load_rig(truth)
    for name in ('top', 'side'):
        T, T_true = measured[name].T_world_camera, expected[name].T_world_camera
        assert 1000 * np.linalg.norm(T[:3, 3] - T_true[:3, 3]) < 5.0
        assert rotation_angle_deg(T, T_true) < 0.5
    # The rest of the config is kept.
    document = yaml.safe_load(out.read_text())
    assert document['pose_estimator'] == yaml.safe_load(
        default_config_path().read_text())['pose_estimator']


def test_calibrate_board_without_a_board_is_one_clear_line(tmp_path, tless_models_dir, capsys):
    bag = tmp_path / 'bag'
    _simulate(tless_models_dir, default_config_path(), bag)
    capsys.readouterr()
    out = str(tmp_path / 'measured.yaml')
    assert main(['calibrate', '--board', '--bag', str(bag), '--out', out]) == 1
    err = capsys.readouterr().err.strip()
    assert err.startswith("tlessbot calibrate: error: camera 'top': no pose from the "
                          'board in 2 image(s): the board is not seen: 0 of its 24 corners')
    assert len(err.splitlines()) == 1
    assert main(['calibrate', '--board', '--bag', str(tmp_path / 'missing'), '--out', out]) == 1
    assert 'bag not found' in capsys.readouterr().err
    assert main(['calibrate', '--board', '--bag', str(bag), '--out', out,
                 '--board-marker-m', '0.07']) == 1
    assert 'smaller than square_length_m' in capsys.readouterr().err


def test_board_writes_a_printable_board(tmp_path, capsys):
    out = tmp_path / 'board.png'
    assert main(['board', '--out', str(out), '--dpi', '150']) == 0
    assert '7 x 5 squares of 55 mm' in capsys.readouterr().out
    image = cv2.imread(str(out), cv2.IMREAD_GRAYSCALE)
    # 385 x 275 mm of squares plus 10 mm margins at 150 dpi.
    assert image.shape == (round(0.295 / 0.0254 * 150), round(0.405 / 0.0254 * 150))
    assert len(detect_board(image, BoardSpec())) == BoardSpec().corner_count
