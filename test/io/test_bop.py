import json

import numpy as np
import pytest

from tlessbot_ros.core.common import default_rig, make_transform
from tlessbot_ros.errors import DatasetError
from tlessbot_ros.io.bop import BopWriter, copy_with_extrinsics, list_splits, read_split
from tlessbot_ros.io.models import load_models
from tlessbot_ros.sim.simulator import SimParams, Simulator


@pytest.fixture(scope='module')
def frames(tless_models_dir):
    models = load_models(tless_models_dir, ids=[6, 19])
    sim = Simulator(models, rig=default_rig(320, 240), params=SimParams(parts_max=2), seed=4)
    return [sim.frame(i) for i in range(2)]


def test_write_read_round_trip(tmp_path, frames):
    for name in ('top', 'side'):
        with BopWriter(tmp_path, f'test_{name}') as writer:
            for frame in frames:
                writer.add(frame.scene_id, frame.im_id, frame.views[name])
    assert list_splits(tmp_path) == ['test_side', 'test_top']
    gt_json = json.loads((tmp_path / 'test_top' / '000000' / 'scene_gt.json').read_text())
    assert set(gt_json) == {'0', '1'}
    images = list(read_split(tmp_path, 'test_side'))
    assert [(i.scene_id, i.im_id) for i in images] == [(0, 0), (0, 1)]
    for image, frame in zip(images, frames):
        view = frame.views['side']
        assert np.array_equal(image.rgb, view.rgb)
        valid = view.depth_mm > 0
        assert np.array_equal(np.isnan(image.depth_m), ~valid)
        assert np.allclose(image.depth_m[valid], view.depth_mm[valid] / 1000.0, atol=1e-6)
        assert np.allclose(image.intrinsics.K, view.intrinsics.K)
        assert (image.intrinsics.width, image.intrinsics.height) == (320, 240)
        assert np.allclose(image.T_world_camera, view.T_world_camera, atol=1e-9)
        assert len(image.gt) == len(view.gt)
        for got, want in zip(image.gt, view.gt):
            assert got.obj_id == want.obj_id
            assert np.allclose(got.T_camera_object, want.T_camera_object, atol=1e-9)
            assert got.bbox_visib == want.bbox_visib
            assert got.visib_fract == pytest.approx(want.visib_fract)
            assert np.array_equal(got.mask, want.mask_visib)
    assert len(list(read_split(tmp_path, 'test_top', limit=1, load_masks=False))) == 1
    assert all(g.mask is None for g in next(read_split(tmp_path, 'test_top',
                                                        load_masks=False)).gt)


def test_errors(tmp_path, frames):
    with pytest.raises(DatasetError, match='not found'):
        list_splits(tmp_path / 'missing')
    (tmp_path / 'junk').mkdir()
    with pytest.raises(DatasetError, match='not a BOP dataset'):
        list_splits(tmp_path)
    with BopWriter(tmp_path, 'test_top') as writer:
        writer.add(0, 0, frames[0].views['top'])
    with pytest.raises(DatasetError, match="no split 'test_side'.*test_top"):
        next(read_split(tmp_path, 'test_side'))
    (tmp_path / 'test_top' / '000000' / 'scene_gt.json').write_text('{broken')
    with pytest.raises(DatasetError, match='scene_gt.json'):
        next(read_split(tmp_path, 'test_top'))


def test_copy_with_the_extrinsics_removed_or_moved(tmp_path, frames):
    source = tmp_path / 'src'
    with BopWriter(source, 'test_side') as writer:
        for frame in frames:
            writer.add(frame.scene_id, frame.im_id, frame.views['side'])
    assert copy_with_extrinsics(source, tmp_path / 'none', lambda T: None) == 2
    cameras = json.loads((tmp_path / 'none/test_side/000000/scene_camera.json').read_text())
    assert all('cam_R_w2c' not in c and 'cam_K' in c for c in cameras.values())
    for kept, copied in zip(read_split(source, 'test_side'), read_split(tmp_path / 'none',
                                                                        'test_side')):
        assert copied.T_world_camera is None
        np.testing.assert_array_equal(copied.depth_m, kept.depth_m)
        np.testing.assert_array_equal(copied.gt[0].T_camera_object, kept.gt[0].T_camera_object)
    raised = make_transform(np.eye(3), [0.0, 0.0, 0.01])
    assert copy_with_extrinsics(source, tmp_path / 'raised', lambda T: raised @ T) == 2
    for kept, moved in zip(read_split(source, 'test_side'), read_split(tmp_path / 'raised',
                                                                       'test_side')):
        np.testing.assert_allclose(moved.T_world_camera, raised @ kept.T_world_camera,
                                   atol=1e-9)
    # the copy of a copy without extrinsics changes nothing more
    assert copy_with_extrinsics(tmp_path / 'none', tmp_path / 'again', lambda T: None) == 0
    with pytest.raises(DatasetError, match='exists'):
        copy_with_extrinsics(source, tmp_path / 'none', lambda T: None)
