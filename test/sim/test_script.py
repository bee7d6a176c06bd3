"""The scripted table: parts rest, then one moves, one goes, one comes."""
import numpy as np
import pytest

from tlessbot_ros.io.bop import read_split
from tlessbot_ros.io.models import load_models
from tlessbot_ros.sim.script import ScriptParams, script_frames, scripted_table
from tlessbot_ros.sim.simulator import Simulator
from tlessbot_ros.tools.cli import main


@pytest.fixture(scope='module')
def sim(tless_models_dir):
    return Simulator(load_models(tless_models_dir, [6, 19]), seed=2)


def test_layouts_follow_the_script(sim):
    params = ScriptParams(rest_frames=2, change_frames=2, parts=3)
    table = scripted_table(sim, params, seed=4)
    first, second = table.layouts
    assert len(first) == 3 and len(second) == 3   # one removed, one added
    assert len({o.obj_id for o in first}) < len(first)   # 3 parts of 2 classes: a pair
    (moved,) = table.moved
    k = table.keys[0].index(moved)
    shift = second[k].T_world_object[:3, 3] - first[k].T_world_object[:3, 3]
    assert np.linalg.norm(shift) == pytest.approx(params.move_m)
    np.testing.assert_allclose(second[k].T_world_object[:3, :3], first[k].T_world_object[:3, :3])
    assert table.removed == ['c'] and table.added == ['d']
    assert table.keys[1] == ["a'", 'b', 'd']
    again = scripted_table(sim, params, seed=4)
    np.testing.assert_allclose(again.layouts[1][2].T_world_object, second[2].T_world_object)
    frames = list(script_frames(sim, table, params))
    assert [len(f.objects) for f in frames] == [3, 3, 3, 3]
    assert frames[0].objects is first and frames[3].objects is second


def test_script_params_refuse_more_changes_than_parts():
    with pytest.raises(ValueError, match='moved \\+ removed <= parts'):
        ScriptParams(parts=1, moved=1, removed=1)


def test_simulate_script_writes_the_changing_table(tmp_path, tless_models_dir, capsys):
    out = tmp_path / 'sim'
    assert main(['simulate', '--models', str(tless_models_dir), '--out', str(out), '--script',
                 '--rest-frames', '2', '--change-frames', '1', '--ids', '6', '19',
                 '--parts-max', '3', '--width', '320', '--height', '240', '--no-masks',
                 '--no-progress']) == 0
    assert 'moved [' in capsys.readouterr().out
    frames = list(read_split(out, 'test_top'))
    assert len(frames) == 3
    poses = [sorted(tuple(np.round(g.T_camera_object[:3, 3], 4)) for g in f.gt) for f in frames]
    assert poses[0] == poses[1] != poses[2]
