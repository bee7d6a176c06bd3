import json

import numpy as np
import pytest

from tlessbot_ros.core.common import transform_points
from tlessbot_ros.core.common.resting import centre_of_mass
from tlessbot_ros.errors import ModelFileError
from tlessbot_ros.io.models import load_models, stable_poses


@pytest.fixture(scope='module')
def two_models(tless_models_dir):
    return load_models(tless_models_dir, ids=[5, 19])


def test_load_units_ids_and_merge(two_models):
    assert sorted(two_models) == [5, 19]
    m = two_models[19]
    assert m.obj_id == 19 and m.name == 'obj_19'
    # obj_19 has 2348 unique vertices and 4692 faces (same as the BOP PLY).
    assert m.vertices.shape == (2348, 3) and m.faces.shape == (4692, 3)
    assert m.faces.dtype == np.int32 and m.vertices.dtype == np.float64
    assert 0.05 < m.diameter_m < 0.15  # metres, not mm
    assert np.allclose(m.extent_m, np.ptp(m.vertices, axis=0))
    pair = np.linalg.norm(m.vertices[:, None] - m.vertices[None, ::7], axis=-1).max()
    assert pair <= m.diameter_m + 1e-9
    assert m.symmetries_discrete is None  # no models_info.json: unknown


def test_load_errors(tmp_path, tless_models_dir):
    with pytest.raises(ModelFileError, match='not found'):
        load_models(tmp_path / 'nope')
    with pytest.raises(ModelFileError, match=r'no obj_NN.stl\|ply\|obj model files in \S+$'):
        load_models(tmp_path)
    (tmp_path / 'Bracket_A.stl').write_bytes(b'solid a\nendsolid\n')   # a CAD folder
    with pytest.raises(ModelFileError, match=r'\(1 meshes of other names: .*tlessbot parts '
                       r'build --models CAD --out PARTS, then given as PARTS/models\)$'):
        load_models(tmp_path)
    (tmp_path / 'Bracket_A.stl').unlink()
    with pytest.raises(ModelFileError, match=r'\[1\]'):
        load_models(tless_models_dir, ids=[1])
    (tmp_path / 'obj_07.stl').write_bytes(b'solid broken\nendsolid\n')
    with pytest.raises(ModelFileError, match='obj_07'):
        load_models(tmp_path)


def test_bop_models_folder_with_info(tmp_path, tless_models_dir, two_models):
    import open3d as o3d

    m = two_models[19]
    mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(m.vertices * 1000.0),
                                     o3d.utility.Vector3iVector(m.faces))
    o3d.io.write_triangle_mesh(str(tmp_path / 'obj_000019.ply'), mesh)
    flip = np.diag([-1.0, -1.0, 1.0, 1.0])
    flip[0, 3] = 2.0  # mm
    info = {'19': {'diameter': 89.0, 'symmetries_discrete': [flip.ravel().tolist()]}}
    (tmp_path / 'models_info.json').write_text(json.dumps(info))
    loaded = load_models(tmp_path)
    assert list(loaded) == [19]
    assert np.allclose(loaded[19].vertices, m.vertices, atol=1e-6)
    (sym,) = loaded[19].symmetries_discrete
    assert sym[0, 3] == pytest.approx(0.002)
    assert loaded[19].symmetries_continuous == []
    listed = loaded[19].listed_symmetries()        # the identity added, the flip kept
    assert len(listed.discrete) == 2 and np.array_equal(listed.discrete[0], np.eye(4))
    assert np.allclose(listed.discrete[1], sym) and listed.continuous == ()
    assert m.listed_symmetries() is None           # an STL without info: unknown


def test_stable_poses_rest_on_plane(two_models):
    for model in two_models.values():
        poses = stable_poses(model)
        assert poses and stable_poses(model) is poses  # cached
        assert sum(p.probability for p in poses) == pytest.approx(1.0)
        assert all(a.probability >= b.probability for a, b in zip(poses, poses[1:]))
        com = centre_of_mass(model.vertices, model.faces)
        for pose in poses[:4]:
            R = pose.T_table_object[:3, :3]
            assert np.allclose(R @ R.T, np.eye(3), atol=1e-9)
            v = transform_points(pose.T_table_object, model.vertices)
            assert v[:, 2].min() == pytest.approx(0.0, abs=1e-9)
            # Support polygon: vertices touching the table; the CoM projects inside its hull.
            c = transform_points(pose.T_table_object, com[None])[0]
            assert c[2] > 0.005
            support = v[v[:, 2] < 1e-6][:, :2]
            assert len(support) >= 3
            from scipy.spatial import Delaunay
            assert Delaunay(support).find_simplex(c[:2]) >= 0


def test_stable_poses_of_a_box_are_its_faces():
    from tlessbot_ros.io.models import ObjectModel

    corners = np.array([[x, y, z] for x in (-.05, .05) for y in (-.02, .02) for z in (-.01, .01)])
    from scipy.spatial import ConvexHull
    faces = ConvexHull(corners).simplices.astype(np.int32)
    box = ObjectModel(obj_id=1, vertices=corners, faces=faces, diameter_m=0.11,
                      extent_m=np.ptp(corners, axis=0))
    poses = stable_poses(box)
    assert len(poses) == 6
    # Lying flat on the big faces is the most likely (largest solid angle).
    top = poses[0].T_table_object[:3, :3]
    assert abs(top[2] @ np.array([0, 0, 1.0])) == pytest.approx(1.0)
    assert poses[0].probability > poses[-1].probability


def test_merge_rolling_poses_of_a_cylinder():
    import trimesh

    from tlessbot_ros.io.models import ObjectModel

    cyl = trimesh.creation.cylinder(radius=0.015, height=0.1, sections=64)
    v = np.asarray(cyl.vertices, dtype=np.float64)
    model = ObjectModel(obj_id=99, vertices=v, faces=np.asarray(cyl.faces, np.int32),
                        diameter_m=0.104, extent_m=np.ptp(v, axis=0))
    many = stable_poses(model)
    merged = stable_poses(model, merge_rolling=True)
    assert len(many) > 60  # one pose per side strip + 2 ends
    assert len(merged) == 3
    assert sum(p.probability for p in merged) == pytest.approx(1.0)
    side = merged[0].T_table_object
    # Lying on the side: the cylinder axis (model z) is horizontal and most likely.
    assert abs(side[2, 2]) < 1e-6 and merged[0].probability > 0.5
    for pose in merged[1:]:
        assert abs(pose.T_table_object[2, 2]) == pytest.approx(1.0)


def test_cached_builds_once_per_key():
    from tlessbot_ros.io.models import ObjectModel

    v = np.eye(3)
    model = ObjectModel(obj_id=1, vertices=v, faces=np.array([[0, 1, 2]]), diameter_m=1.0,
                        extent_m=np.ones(3))
    calls = []
    first = model.cached('thing', lambda: calls.append(1) or [1, 2])
    assert model.cached('thing', lambda: calls.append(1) or [3]) is first and calls == [1]
    assert model.cached(('other', 2), lambda: 5) == 5
