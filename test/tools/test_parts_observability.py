"""tlessbot parts build's check of what the rig can see: a 5° turn of a round part about its
axis is seen when a large feature breaks its symmetry, not when only a tiny one does."""
import numpy as np
import open3d as o3d
import pytest

from tlessbot_ros.core.common import default_rig, raycasting_scene
from tlessbot_ros.core.pose import ObservabilityParams, ViewOfTable, changed_pixels
from tlessbot_ros.core.pose.observability import turned
from tlessbot_ros.io.models import ObjectModel
from tlessbot_ros.tools.support.observability import part_turns, unseen_note, unseen_turns
from tlessbot_ros.tools.support.parts_build import self_check_table


def _round_part(key_mm: float) -> ObjectModel:
    """A disc 30 mm across and 12 mm high (64 sides) with a cube ``key_mm`` wide on its rim."""
    disc = o3d.geometry.TriangleMesh.create_cylinder(radius=0.015, height=0.012,
                                                     resolution=64, split=1)
    key = o3d.geometry.TriangleMesh.create_box(key_mm / 1000, key_mm / 1000, key_mm / 1000)
    key.translate((0.015 - key_mm / 2000, -key_mm / 2000, -key_mm / 2000))
    mesh = disc + key
    v, f = np.asarray(mesh.vertices, np.float64), np.asarray(mesh.triangles, np.int32)
    size = v.max(axis=0) - v.min(axis=0)
    return ObjectModel(obj_id=1, vertices=v, faces=f, diameter_m=float(np.linalg.norm(size)),
                       extent_m=size, symmetries_discrete=[], symmetries_continuous=[])


@pytest.fixture(scope='module')
def rig():
    return default_rig()


def test_a_tiny_key_leaves_the_turn_about_the_axis_unseen_a_large_one_does_not(rig):
    tiny = unseen_turns(part_turns(_round_part(0.5), rig))
    large = unseen_turns(part_turns(_round_part(8.0), rig))
    assert {a['axis'] for a in tiny['axes'] if a['turn_deg'] == 5.0} & {'z', 'yaw'}, tiny
    assert all(a['changed_px'] < ObservabilityParams().min_px for a in tiny['axes'])
    assert not tiny['every_axis']          # tilting it off its face is seen (and levelled)
    assert [a for a in large['axes'] if a['turn_deg'] == 5.0] == [], large
    assert unseen_note(tiny).endswith('px)') and unseen_note(None) == '-'
    assert unseen_note({'axes': [], 'every_axis': False}) == '-'


def test_a_half_turn_the_list_leaves_out_is_reported_when_the_rig_cannot_tell_it(rig):
    # the key sits half-way up the disc's rim: turned over about x the part maps onto itself
    # (a symmetry its empty list leaves out); turned over about y the key goes to the far side
    record = unseen_turns(part_turns(_round_part(8.0), rig))
    turns = {(a['axis'], a['turn_deg']) for a in record['axes']}
    assert ('x', 180.0) in turns and ('y', 180.0) not in turns
    model = _round_part(8.0)
    model.symmetries_discrete = [np.diag([1.0, -1.0, -1.0, 1.0])]     # now listed
    assert unseen_turns(part_turns(model, rig))['axes'] == []


def test_pixels_change_with_the_turn_and_not_without(rig):
    model = _round_part(8.0)
    scene, points = raycasting_scene(model.vertices, model.faces), model.vertices
    T = np.eye(4)
    T[2, 3] = 0.006                                  # lying on its end, centred
    params = ObservabilityParams()
    view = ViewOfTable(rig['side'].intrinsics, rig['side'].T_world_camera)
    assert changed_pixels(scene, points, T, T, view, params) == (0, 0, 0)
    small = changed_pixels(scene, points, T, turned(T, np.eye(3)[2], np.zeros(3), 5.0), view,
                           params)
    larger = changed_pixels(scene, points, T, turned(T, np.eye(3)[2], np.zeros(3), 30.0), view,
                            params)
    assert 0 < small[2] < larger[2] and larger[2] >= max(larger[:2])


def test_the_self_check_table_says_which_turns_are_not_seen():
    rows = [{'name': 'nut', 'seen': 4, 'pose': 0.25, 'top1': 1.0, 'detected': 1.0,
             'lookalikes': [], 'unseen': 'yaw (2 px)'},
            {'name': 'block', 'seen': 4, 'pose': 1.0, 'top1': 1.0, 'detected': 1.0,
             'lookalikes': [], 'unseen': '-'}]
    table = self_check_table(rows, {'frames': 2, 'pose': 0.6, 'top1': 1.0, 'detected': 1.0,
                                    'false_pos_per_frame': 0.0}).splitlines()
    assert 'turns not seen' in table[0]
    assert '| yaw (2 px) | hard |' in table[2] and '| - |  |' in table[3]
    assert len({line.count('|') for line in table}) == 1


def test_parts_observe_prints_one_row_per_part(tmp_path, capsys):
    from tlessbot_ros.io.parts import write_mesh
    from tlessbot_ros.tools.cli import main

    for name, key in (('disc_key', 8.0), ('disc_plain', 0.5)):
        model = _round_part(key)
        write_mesh(tmp_path / f'{name}.stl', model.vertices * 1000.0, model.faces)
    assert main(['parts', 'observe', '--models', str(tmp_path)]) == 0
    out = capsys.readouterr().out.splitlines()
    assert 'turns not seen (px changed)' in out[0]
    assert [line.split('|')[1].strip() for line in out[2:4]] == ['disc_key', 'disc_plain']
    assert out[-1].startswith('2 parts in ')
