"""The flat test parts made by code: closed meshes of the stated thickness, STL in mm."""
from __future__ import annotations

import numpy as np
import pytest

from tlessbot_ros.tools.support import flat_parts


def test_parts_are_closed_and_as_thick_as_stated():
    trimesh = pytest.importorskip('trimesh')
    outline, thickness, chamfer = flat_parts.PARTS[6]
    vertices, faces = flat_parts.part_mesh(outline, thickness, chamfer, step_mm=0.8, faces=3000)
    mesh = trimesh.Trimesh(vertices, faces)
    assert mesh.is_watertight and mesh.volume > 0
    assert np.ptp(vertices[:, 2]) == pytest.approx(thickness, abs=0.5)
    assert np.ptp(vertices[:, 0]) == pytest.approx(60.0, abs=1.0)   # the 60 x 40 plate


@pytest.mark.parametrize('obj_id', sorted(flat_parts.PARTS))
def test_no_outline_is_its_own_mirror_image(obj_id):
    # a part turned over shows its outline mirrored: about any in-plane axis through the
    # centre, mirrored and turned, the outline must differ somewhere (here: x and y mirrors
    # and the half turn)
    outline = flat_parts.PARTS[obj_id][0]
    x, y = np.meshgrid(np.linspace(-70, 70, 281), np.linspace(-70, 70, 281))
    inside = outline(x, y) <= 0
    for other in (outline(-x, y), outline(x, -y), outline(-x, -y)):
        assert np.mean(inside != (other <= 0)) > 0.002


def test_the_look_alike_pair_differs_by_one_hole():
    one, two = flat_parts.PARTS[1][0], flat_parts.PARTS[2][0]
    x, y = np.meshgrid(np.linspace(-45, 45, 181), np.linspace(-25, 25, 101))
    differs = (one(x, y) <= 0) != (two(x, y) <= 0)
    assert 0 < differs.mean() < 0.01
    assert np.all(np.hypot(x[differs], y[differs] - 14) <= 3.5)


def test_main_writes_stl_in_millimetres(tmp_path, monkeypatch):
    monkeypatch.setattr(flat_parts, 'part_mesh',
                        lambda *a, **k: (np.array([[0, 0, 0], [60, 0, 0], [0, 40, 0],
                                                   [0, 0, 3.0]]),
                                         np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])))
    assert flat_parts.main([str(tmp_path), '--ids', '6']) == 0
    assert (tmp_path / 'obj_06.stl').stat().st_size > 0
    # no symmetry listed: a scorer must not take a plate turned over for the same pose
    import json
    info = json.loads((tmp_path / 'models_info.json').read_text())['6']
    assert info['symmetries_discrete'] == [] and info['diameter'] == pytest.approx(
        np.hypot(60, 40), abs=0.01)
