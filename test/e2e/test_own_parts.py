"""Your own parts, as the README's "Your own parts" runs them: CAD files made by code (not
T-LESS) -> tlessbot parts build -> a bag of those parts -> the graph (real processes over DDS)
publishes /objects/<name>/pose. A parts folder that is broken or built for another rig is
refused before anything starts."""
from __future__ import annotations

import json

import pytest
import yaml

from tlessbot_ros.io.cache import derived_cache_path
from tlessbot_ros.io.config import default_config_path
from tlessbot_ros.io.parts import open_parts_folder
from tlessbot_ros.tools.cli import main
from tlessbot_ros.tools.support.graph_run import run_graph_on_bag

pytestmark = [pytest.mark.ros, pytest.mark.rosbag, pytest.mark.slow]

PARTS = ('bracket_short', 'plate_holes2', 'tube')
# A quick classifier (fewer turntable views, no scenes) keeps the test short; the README's
# build uses the packaged recipe.
QUICK = ['--recipe', 'defaults', '--train-arg=--steps-deg=20', '--train-arg=--positions=2']


@pytest.fixture(scope='module')
def own_parts(tmp_path_factory):
    root = tmp_path_factory.mktemp('own_parts')
    cad, parts, bag = root / 'my_cad', root / 'my_parts', root / 'my_bag'
    assert main(['parts', 'generate', '--out', str(cad), '--names', *PARTS]) == 0
    # the self-check on the smoothed depth a real stereo camera gives (the bag below: per pixel)
    assert main(['parts', 'build', '--models', str(cad), '--out', str(parts), *QUICK,
                 '--check-frames', '1', '--check-depth', 'smoothed']) == 0
    assert main(['simulate', '--models', str(parts / 'models'), '--bag', str(bag),
                 '--frames', '3', '--parts-min', '3', '--parts-max', '3', '--seed', '41',
                 '--cloud-stride', '4', '--no-masks', '--no-progress']) == 0
    return parts, bag


def test_parts_folder_holds_what_a_cell_needs(own_parts):
    parts, _ = own_parts
    folder = open_parts_folder(parts)
    assert folder.names == {1: 'bracket_short', 2: 'plate_holes2', 3: 'tube'}
    manifest = json.loads((parts / 'manifest.json').read_text())
    by_name = {p['name']: p for p in manifest['parts']}
    assert by_name['plate_holes2']['size_mm'] == pytest.approx([60, 40, 4], abs=0.5)
    assert 'continuous' in by_name['tube']['symmetry']
    assert set(manifest['build_s']) == {'meshes + symmetries', 'turns the rig sees',
                                        'templates', 'classifier', 'manifest',
                                        'start-up caches', 'self-check'}
    # the pose node's first start reads the derived arrays the build cached
    assert derived_cache_path(folder.templates).is_file()
    assert all('unseen_turns_5deg' in part for part in manifest['parts'])
    table = (parts / 'self_check.md').read_text()
    assert all(f'| {name} |' in table for name in PARTS)
    assert '1 frames, smoothed depth' in table
    assert manifest['self_check']['depth_model'] == 'smoothed'
    # the evaluation behind the table stays with the folder (its path is printed)
    assert (parts / 'self_check' / 'report.md').is_file()


def test_graph_publishes_named_poses(own_parts):
    parts, bag = own_parts
    names = open_parts_folder(parts).names
    run = run_graph_on_bag(bag, config=default_config_path(), lockstep=True,
                           ros_args=['-p', f'parts_path:={parts}'], part_names=names,
                           startup_timeout_s=600.0)
    assert run.poses, 'no pose on any /objects/<name>/pose'
    assert {pose.obj_id for pose in run.poses} <= set(names)


def test_broken_or_foreign_folders_refused_at_start(own_parts, tmp_path, capsys):
    parts, bag = own_parts
    config = yaml.safe_load(default_config_path().read_text())
    config['/**']['ros__parameters']['rig']['side']['position_m'] = [0.0, -0.4, 0.5]
    moved = tmp_path / 'moved.yaml'
    moved.write_text(yaml.safe_dump(config, sort_keys=False))
    assert main(['launch', '--config', str(moved), '--parts', str(parts), '--replay',
                 str(bag)]) == 1
    err = capsys.readouterr().err.strip()
    assert 'was built for another rig' in err and len(err.splitlines()) == 1
    broken = tmp_path / 'broken'
    broken.mkdir()
    for item in parts.iterdir():
        if item.name != 'templates.npz':
            (broken / item.name).symlink_to(item)
    assert main(['launch', '--parts', str(broken), '--replay', str(bag)]) == 1
    assert 'has no templates.npz' in capsys.readouterr().err
