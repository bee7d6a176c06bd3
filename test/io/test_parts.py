"""Parts folders: CAD files of any name, meshes checked, a folder refused with one reason."""
import json

import numpy as np
import pytest

from tlessbot_ros.core.common import default_rig
from tlessbot_ros.errors import ModelFileError, PartNameError
from tlessbot_ros.io.parts import (
    FORMAT,
    REQUIRED,
    PartsFolderError,
    cad_parts,
    check_part_mesh,
    model_names,
    open_parts_folder,
    rig_summary,
    write_mesh,
)
from tlessbot_ros.tools.support.part_generator import mesh_part, part_shapes


def _cube(edge_mm=20.0):
    v = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], float) * edge_mm
    f = np.array([[0, 2, 1], [1, 2, 3], [4, 5, 6], [5, 7, 6], [0, 1, 4], [1, 5, 4],
                  [2, 6, 3], [3, 6, 7], [0, 4, 2], [2, 4, 6], [1, 3, 5], [3, 7, 5]], np.int32)
    return v, f


def test_any_file_names_become_part_names(tmp_path):
    v, f = _cube()
    for name in ('zeta.stl', 'alpha.ply', 'obj_07.stl', 'Bracket_2.obj'):
        write_mesh(tmp_path / name, v, f)
    parts = cad_parts(tmp_path)
    assert [(p.obj_id, p.name) for p in parts] == [
        (1, 'Bracket_2'), (2, 'alpha'), (3, 'zeta'), (7, 'obj_07')]


def test_models_folders_name_their_parts(tmp_path):
    """Reports name parts as the graph does: a parts folder's manifest, else the CAD stems;
    obj_NN files (T-LESS, BOP) and unreadable names keep the default."""
    v, f = _cube()
    cad = tmp_path / 'cad'
    cad.mkdir()
    for name in ('zeta.stl', 'obj_07.stl', 'obj_000009.ply'):
        write_mesh(cad / name, v, f)
    assert model_names(cad) == {1: 'zeta'}
    parts = tmp_path / 'parts'
    (parts / 'models').mkdir(parents=True)
    write_mesh(parts / 'models' / 'obj_01.ply', v, f)
    (parts / 'manifest.json').write_text(json.dumps(
        {'format': FORMAT, 'parts': [{'id': 1, 'name': 'bracket_l', 'size_mm': [20, 20, 20]}]}))
    assert model_names(parts / 'models') == {1: 'bracket_l'}
    (parts / 'manifest.json').write_text('{"parts": [{"id": 1, "name": "no good"}]}')
    assert model_names(parts / 'models') == {}
    write_mesh(cad / 'M6 bolt.stl', v, f)
    assert model_names(cad) == {} and model_names(tmp_path / 'nowhere') == {}


def test_bad_names_and_twins_refused(tmp_path):
    v, f = _cube()
    write_mesh(tmp_path / 'M6 bolt.stl', v, f)
    with pytest.raises(PartNameError, match='rename the file to M6_bolt.stl'):
        cad_parts(tmp_path)
    write_mesh(tmp_path / 'Bracket-A.stl', v, f)
    write_mesh(tmp_path / 'flange.stl', v, f)
    with pytest.raises(PartNameError) as refused:   # every file to rename, in one message
        cad_parts(tmp_path)
    lines = str(refused.value).splitlines()
    assert lines[0] == '2 of 3 CAD files cannot be used:'
    assert 'rename the file to Bracket_A.stl' in lines[1]
    assert 'rename the file to M6_bolt.stl' in lines[2] and len(lines) == 3
    (tmp_path / 'M6 bolt.stl').unlink()
    (tmp_path / 'Bracket-A.stl').unlink()
    write_mesh(tmp_path / 'plate.stl', v, f)
    write_mesh(tmp_path / 'plate.ply', v, f)
    with pytest.raises(ModelFileError, match='same name'):
        cad_parts(tmp_path)


def test_unusable_meshes_say_why():
    v, f = _cube()
    assert check_part_mesh(v / 1000.0, f, name='cube.stl') == []
    # --units is the folder's: the message says so, and how to scale the one file instead
    with pytest.raises(ModelFileError, match=r'probably in m; --units m if all the files are '
                       r'in m, else scale it to mm \(x1000\)$'):
        check_part_mesh(v / 1e6, f, name='cube.stl')            # a file in metres read as mm
    with pytest.raises(ModelFileError, match=r'probably in mm; leave out --units m if all the '
                       r'files are in mm, else scale it to m \(x0.001\)$'):
        check_part_mesh(v, f, name='cube.stl', units='m')       # mm read as metres
    with pytest.raises(ModelFileError, match=r'read in mm: a part is 4 mm to 1.5 m across: '
                       'check its units') as refused:
        check_part_mesh(v * 1000.0, f, name='cube.stl')         # micrometres: not "in m"
    assert '--units m' not in str(refused.value).split(':')[1]
    flat = v / 1000.0 * np.array([1.0, 1.0, 0.0])
    with pytest.raises(ModelFileError, match='degenerate'):
        check_part_mesh(flat, f, name='sheet.stl')
    with pytest.raises(ModelFileError, match='not closed'):
        check_part_mesh(v / 1000.0, f[:8], name='open.stl')
    assert 'not closed' in check_part_mesh(v / 1000.0, f[:11], name='hole.stl',
                                           max_open_fraction=0.5)[0]


def test_large_hole_in_a_fine_mesh_is_warned_of():
    """Half of a fine tube cut away: under 1 % of its edges are open, but its hole rim is
    four times the part's size; the rim alone gets the warning."""
    sdf, (low, high) = part_shapes()['tube']
    v, f = mesh_part(sdf, low, high, spacing_mm=0.5)
    centres = v[f].mean(axis=1)[:, 0]
    cut = f[centres < np.median(centres)]           # one half along the tube's axis
    warnings = check_part_mesh(v / 1000.0, cut, name='tube_open.stl')
    assert len(warnings) == 1 and 'tube_open.stl is not closed (0.9 %' in warnings[0]
    assert 'mm of hole rim on a part 57 mm across' in warnings[0]
    assert check_part_mesh(v / 1000.0, cut, name='t', max_rim_fraction=10.0) == []
    assert check_part_mesh(v / 1000.0, f, name='tube.stl') == []


def test_read_meshes_lists_every_unusable_file(tmp_path, capsys):
    from tlessbot_ros.io.parts import problems_listed
    from tlessbot_ros.tools.support.parts_build import read_meshes

    v, f = _cube()
    write_mesh(tmp_path / 'good.stl', v, f)
    write_mesh(tmp_path / 'block_m.stl', v / 1000.0, f)
    write_mesh(tmp_path / 'sheet.stl', v * np.array([1.0, 1.0, 0.0]), f)
    with pytest.raises(ModelFileError) as refused:
        read_meshes(cad_parts(tmp_path), 'mm')
    lines = str(refused.value).splitlines()
    assert lines[0] == '2 of 3 CAD files cannot be used:'
    assert lines[1].startswith('  block_m.stl is 3.464e-05 m across read in mm')
    assert lines[2].startswith('  sheet.stl is degenerate')
    assert problems_listed(['one'], 3) == 'one'
    (tmp_path / 'block_m.stl').unlink()
    (tmp_path / 'sheet.stl').unlink()
    assert set(read_meshes(cad_parts(tmp_path), 'mm')) == {'good'}


def test_generated_part_is_closed_and_outward():
    sdf, (low, high) = part_shapes()['strip_slotted']
    v, f = mesh_part(sdf, low, high, spacing_mm=0.5)
    assert check_part_mesh(v / 1000.0, f, name='strip') == []
    tri = v[f]
    volume = np.einsum('ij,ij->i', tri[:, 0], np.cross(tri[:, 1], tri[:, 2])).sum() / 6.0
    holes, corners = 3 * np.pi * 2.0 ** 2 * 3.0, 4 * (2.0 * 2.0 / 2) * 3.0   # mm^3
    assert volume == pytest.approx(80 * 16 * 3 - corners - holes, rel=0.02)
    assert np.ptp(v, axis=0) == pytest.approx([80, 16, 3], abs=0.5)


def _folder(tmp_path, rig):
    (tmp_path / 'models').mkdir()
    for name in REQUIRED:
        (tmp_path / name).write_text('{}')
    manifest = {'format': FORMAT, 'rig': rig_summary(rig),
                'parts': [{'id': 1, 'name': 'plate'}, {'id': 2, 'name': 'bracket'}]}
    (tmp_path / 'manifest.json').write_text(json.dumps(manifest))
    return tmp_path


def test_parts_folder_refused_with_one_reason(tmp_path):
    rig = default_rig()
    folder = open_parts_folder(_folder(tmp_path, rig), rig=rig)
    assert folder.names == {1: 'plate', 2: 'bracket'}
    assert folder.templates == tmp_path / 'templates.npz'
    moved = default_rig()
    moved.cameras['side'].T_world_camera[2, 3] += 0.1
    with pytest.raises(PartsFolderError, match='built for another rig .*10 cm'):
        open_parts_folder(tmp_path, rig=moved)
    with pytest.raises(PartsFolderError, match='another rig'):
        open_parts_folder(tmp_path, side_pose=moved['side'].T_world_camera)
    (tmp_path / 'classifier.npz').unlink()
    with pytest.raises(PartsFolderError, match='has no classifier.npz: rebuild it'):
        open_parts_folder(tmp_path)
    with pytest.raises(PartsFolderError, match='not found'):
        open_parts_folder(tmp_path / 'nowhere')
