"""Whether the rig can resolve a part's true pose in a scene: a turn about an axis the part is
round about is never seen unless listed, a keyed block's turns and half turns are, and a part
hidden behind another or beside a twin that shows no difference is not resolvable."""
import numpy as np
import open3d as o3d
import pytest

from tlessbot_ros.core.common import (
    centre_of_mass,
    default_rig,
    raycasting_scene,
    sample_surface,
)
from tlessbot_ros.core.pose import ObservabilityParams, ViewOfTable
from tlessbot_ros.core.pose.resolvability import PartShape, posed_scene, resolvability


def _shape(mesh: o3d.geometry.TriangleMesh, *, continuous: bool = False) -> PartShape:
    v, f = np.asarray(mesh.vertices, np.float64), np.asarray(mesh.triangles, np.int32)
    points = sample_surface(v, f, 3000, seed=0)[0]
    return PartShape(raycasting_scene(v, f), points, centre_of_mass(v, f),
                     continuous_axes=[np.array([0.0, 0.0, 1.0])] if continuous else [])


def _disc() -> o3d.geometry.TriangleMesh:
    """A disc 40 mm across and 10 mm high about its model z (64 sides), centred."""
    return o3d.geometry.TriangleMesh.create_cylinder(radius=0.02, height=0.01, resolution=64)


def _keyed_block(key_mm: float = 10.0) -> o3d.geometry.TriangleMesh:
    """A block 60 x 40 x 20 mm, centred, with a cube ``key_mm`` wide on one end of its top."""
    block = o3d.geometry.TriangleMesh.create_box(0.06, 0.04, 0.02).translate((-0.03, -0.02, -0.01))
    k = key_mm / 1000
    key = o3d.geometry.TriangleMesh.create_box(k, k, k).translate((0.03 - k, -k / 2, 0.01))
    return block + key


def _on_table(shape: PartShape, yaw_deg: float = 20.0) -> np.ndarray:
    """Lying with its model z up at the table's origin, its lowest point on z = 0."""
    T = np.eye(4)
    c, s = np.cos(np.radians(yaw_deg)), np.sin(np.radians(yaw_deg))
    T[:2, :2] = [[c, -s], [s, c]]
    T[2, 3] = -float(shape.points[:, 2].min())
    return T


@pytest.fixture(scope='module')
def views():
    return [ViewOfTable(c.intrinsics, c.T_world_camera) for c in default_rig().cameras.values()]


def test_a_turn_about_an_unlisted_round_axis_is_never_resolved_a_listed_one_is_no_doubt(views):
    params = ObservabilityParams()
    plain = _shape(_disc())
    found = resolvability(plain, _on_table(plain), views, params)
    assert not found.resolvable
    assert {name for name, angle, _ in found.unseen_turns if angle < 90} & {'z', 'yaw'}
    assert set(found.causes) == {'turn', 'half turn'}     # a plain disc flipped looks the same
    listed = _shape(_disc(), continuous=True)
    assert [t for t in resolvability(listed, _on_table(listed), views, params).unseen_turns
            if t[0] in ('z', 'yaw')] == []


def test_a_keyed_block_on_its_base_is_resolved_even_turned_end_for_end(views):
    block = _shape(_keyed_block())
    found = resolvability(block, _on_table(block), views, ObservabilityParams())
    assert found.resolvable, found
    assert found.causes == ()


def test_a_block_hidden_under_a_lid_in_both_cameras_is_not_resolvable(views):
    block = _shape(_keyed_block())
    lid = o3d.geometry.TriangleMesh.create_box(1.0, 1.0, 0.002).translate((-0.5, -0.5, 0.05))
    others = posed_scene([(np.asarray(lid.vertices), np.asarray(lid.triangles), np.eye(4))])
    found = resolvability(block, _on_table(block), views, ObservabilityParams(), others=others)
    assert not found.resolvable
    assert all(px == 0 for _, _, px in found.unseen_turns)
    assert posed_scene([]) is None


def test_a_twin_is_resolved_only_when_the_views_show_its_difference(views):
    block = _shape(_keyed_block())
    params = ObservabilityParams()
    same = resolvability(block, _on_table(block), views, params, twins={7: block})
    assert same.unseen_twins == ((7, 0),) and same.causes == ('twin',)
    bigger_key = _shape(_keyed_block(key_mm=16.0))
    other = resolvability(block, _on_table(block), views, params, twins={8: bigger_key})
    assert other.unseen_twins == () and other.resolvable


def test_the_half_turn_about_the_vertical_is_measured_unless_it_is_a_symmetry():
    from tlessbot_ros.core.pose.observability import measured_turns

    params = ObservabilityParams()
    block, disc = _shape(_keyed_block()), _shape(_disc(), continuous=True)
    level = np.array([1.0, 0.0, 0.0])           # standing on an end: the model x is vertical
    assert ('yaw', None, 180.0) in measured_turns(block.points, params, up_o=level)
    assert ('yaw', None, 180.0) not in measured_turns(block.points, params)
    up = np.array([0.0, 0.0, 1.0])              # the disc lying on its face: round about it
    assert ('yaw', None, 180.0) not in measured_turns(
        disc.points, params, continuous_axes=disc.continuous_axes, up_o=up)
