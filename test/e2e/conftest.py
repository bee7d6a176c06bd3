"""Shared end-to-end fixtures: a small simulated bag of a rig moved from config/cell.yaml."""
from __future__ import annotations

import pytest
import yaml

from tlessbot_ros.io.config import default_config_path
from tlessbot_ros.tools.cli import main

FPS = 2.0     # test_free_running.py's FPS and FRAMES: keep them the same
FRAMES = 6


@pytest.fixture(scope='session')
def moved_rig_bag(tless_models_dir, tmp_path_factory):
    """A simulated bag (2 frames/s) of a rig moved a few cm and degrees from cell.yaml, and
    the YAML that holds that rig."""
    root = tmp_path_factory.mktemp('free_running')
    config = yaml.safe_load(default_config_path().read_text())
    rig = config['/**']['ros__parameters']['rig']
    rig['top']['position_m'], rig['top']['look_at_m'] = [0.03, -0.02, 1.12], [0.02, 0.01, 0.0]
    rig['side']['position_m'], rig['side']['look_at_m'] = [0.04, -0.24, 0.58], [0.03, -0.02, 0.0]
    path = root / 'moved.yaml'
    path.write_text(yaml.safe_dump(config, sort_keys=False))
    bag = root / 'bag'
    assert main(['simulate', '--models', str(tless_models_dir), '--out', str(root / 'bop'),
                 '--bag', str(bag), '--fps', str(FPS), '--frames', str(FRAMES), '--seed', '606',
                 '--parts-min', '2', '--parts-max', '5', '--config', str(path),
                 '--cloud-stride', '4', '--no-masks', '--no-progress']) == 0
    return bag, path
