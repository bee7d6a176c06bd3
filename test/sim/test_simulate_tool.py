import json

import numpy as np

from tlessbot_ros.io.bop import list_splits, read_split
from tlessbot_ros.tools.cli import main


def test_simulate_writes_two_view_bop(tmp_path, tless_models_dir, capsys):
    out = tmp_path / 'sim'
    rc = main(['simulate', '--models', str(tless_models_dir), '--out', str(out), '--frames', '2',
               '--ids', '6', '19', '--parts-max', '2', '--width', '320', '--height', '240',
               '--seed', '3', '--backgrounds', '--no-progress'])
    assert rc == 0
    assert list_splits(out) == ['background_side', 'background_top', 'test_side', 'test_top']
    (bg,) = list(read_split(out, 'background_side', limit=1))
    assert bg.gt == [] and (bg.scene_id, bg.im_id) == (0, 0)
    top = list(read_split(out, 'test_top'))
    side = list(read_split(out, 'test_side'))
    assert [(i.scene_id, i.im_id) for i in top] == [(i.scene_id, i.im_id) for i in side]
    assert len(top) == 2
    for a, b in zip(top, side):
        assert a.rgb.shape == (240, 320, 3)
        assert a.intrinsics.fx == 307.5  # 615 px at 640 wide, scaled
        assert [g.obj_id for g in a.gt] == [g.obj_id for g in b.gt]
        # Both views see the same world pose of each part.
        for ga, gb in zip(a.gt, b.gt):
            assert np.allclose(a.T_world_camera @ ga.T_camera_object,
                               b.T_world_camera @ gb.T_camera_object, atol=1e-6)
    info = json.loads((out / 'models_info.json').read_text())
    assert set(info) == {'6', '19'} and 50 < info['19']['diameter'] < 150
    # the folder lists no symmetries: detected as tlessbot models-info does (6: a half turn)
    (turn,) = info['6']['symmetries_discrete']
    assert np.allclose(np.reshape(turn, (4, 4))[:3, :3], np.diag([-1, -1, 1]), atol=0.01)
    camera = json.loads((out / 'camera_top.json').read_text())
    assert camera['width'] == 320


def test_simulate_user_errors(tmp_path, tless_models_dir, capsys):
    assert main(['simulate', '--models', str(tmp_path / 'none'), '--out', str(tmp_path)]) == 1
    assert 'model folder not found' in capsys.readouterr().err
    assert main(['simulate', '--models', str(tless_models_dir)]) == 1
    assert 'nothing to write' in capsys.readouterr().err
    assert main(['simulate', '--models', str(tless_models_dir), '--out', str(tmp_path),
                 '--materials', 'gold']) == 1
    assert 'unknown materials' in capsys.readouterr().err


def test_bench_sim_prints_breakdown(tless_models_dir, capsys):
    rc = main(['bench', 'sim', '--models', str(tless_models_dir), '--ids', '6', '19',
               '--frames', '2', '--parts', '2', '--width', '160', '--height', '120',
               '--no-progress'])
    assert rc == 0
    out = capsys.readouterr().out
    assert 'ms/frame' in out
    for stage in ('raycast', 'shading', 'noise'):
        assert f'| {stage} |' in out


def test_simulate_writes_the_cameras_asked_for(tmp_path, tless_models_dir, capsys):
    common = ['simulate', '--models', str(tless_models_dir), '--frames', '1', '--ids', '6',
              '19', '--parts-max', '2', '--width', '320', '--height', '240', '--seed', '3',
              '--no-progress']
    rc = main([*common, '--out', str(tmp_path / 'both')])
    assert rc == 0
    rc = main([*common, '--out', str(tmp_path / 'side'), '--cameras', 'side'])
    assert rc == 0 and 'of 1 camera(s)' in capsys.readouterr().out
    assert list_splits(tmp_path / 'side') == ['test_side']
    (one,) = list(read_split(tmp_path / 'side', 'test_side'))
    (both,) = list(read_split(tmp_path / 'both', 'test_side'))
    np.testing.assert_array_equal(one.rgb, both.rgb)   # the scene of the whole rig
    assert main([*common, '--out', str(tmp_path / 'x'), '--cameras', 'front']) == 1
    assert '--cameras front: the rig has the cameras top, side' in capsys.readouterr().err


def test_simulate_pile_packs_the_parts(tmp_path, tless_models_dir):
    """--pile: every part lies next to another one."""
    from tlessbot_ros.core.common import transform_points

    assert main(['simulate', '--models', str(tless_models_dir), '--frames', '3', '--ids', '6',
                 '19', '--parts-min', '5', '--parts-max', '5', '--width', '320', '--height',
                 '240', '--seed', '3', '--cameras', 'side', '--no-progress', '--no-masks',
                 '--pile', '--out', str(tmp_path)]) == 0
    for image in read_split(tmp_path, 'test_side'):
        assert len(image.gt) >= 3
        centres = np.array([transform_points(image.T_world_camera, g.T_camera_object[:3, 3:].T)
                            [0, :2] for g in image.gt])
        gaps = np.linalg.norm(centres[:, None] - centres[None], axis=-1)
        np.fill_diagonal(gaps, np.inf)
        assert gaps.min(axis=1).max() < 0.12   # both parts are 6-10 cm across


def test_simulate_writes_the_listed_symmetries(tmp_path, tless_models_dir):
    """A models folder with a models_info.json: the dataset lists the same symmetries, so a
    tool that scores it (bop_toolkit reads the dataset's models_info) knows them."""
    models = tmp_path / 'models'
    models.mkdir()
    for obj_id in (5, 19):
        (models / f'obj_{obj_id:02d}.stl').symlink_to(tless_models_dir / f'obj_{obj_id:02d}.stl')
    turn = [-1.0, 0, 0, 0, 0, -1.0, 0, 0, 0, 0, 1.0, 0, 0, 0, 0, 1.0]
    (models / 'models_info.json').write_text(json.dumps(
        {'5': {'symmetries_discrete': [turn]}, '19': {}}))
    out = tmp_path / 'sim'
    assert main(['simulate', '--models', str(models), '--out', str(out), '--frames', '1',
                 '--parts-max', '1', '--width', '160', '--height', '120', '--no-masks',
                 '--no-progress']) == 0
    info = json.loads((out / 'models_info.json').read_text())
    assert np.allclose(info['5']['symmetries_discrete'], [turn])
    assert 'symmetries_discrete' not in info['19'] and 'symmetries_continuous' not in info['19']
    assert info['19']['diameter'] > 50
