"""tlessbot evaluate end to end (--oracle none) on a BOP set of one camera, depth on some
frames only and no visible masks: the shape of a real RGB-D set (issue 41)."""
from __future__ import annotations

import json
import shutil
from types import SimpleNamespace

import numpy as np
import pytest

from tlessbot_ros.core.common import CameraIntrinsics, make_transform
from tlessbot_ros.io.bop import BopGroundTruth, BopImage
from tlessbot_ros.tools.cli import main
from tlessbot_ros.tools.support.eval_scoring import with_visible_masks

IDS = (5, 11)


@pytest.fixture(scope='module')
def one_camera(tless_models_dir, tmp_path_factory):
    """A one-split set (``test``), depth on frame 0 only, no mask_visib/, and its models."""
    root = tmp_path_factory.mktemp('one_camera')
    models = root / 'models'
    models.mkdir()
    for obj_id in IDS:
        shutil.copy(tless_models_dir / f'obj_{obj_id:02d}.stl', models)
    simulated = root / 'sim'
    assert main(['simulate', '--models', str(models), '--out', str(simulated), '--frames', '3',
                 '--ids', *map(str, IDS), '--parts-min', '2', '--parts-max', '2',
                 '--width', '320', '--height', '240', '--no-progress', '--seed', '5']) == 0
    data = root / 'bop'
    shutil.copytree(simulated / 'test_side', data / 'test')
    for path in sorted(data.glob('test/*/depth/*.png'))[1:]:
        path.unlink()
    for folder in data.glob('test/*/mask_visib'):
        shutil.rmtree(folder)
    return models, data


def test_the_whole_pipeline_runs_on_one_camera_and_skips_pose_without_depth(
        one_camera, tmp_path, capsys):
    models, data = one_camera
    classifier, templates = tmp_path / 'c.npz', tmp_path / 't.npz'
    assert main(['train', '--models', str(models), '--steps-deg', '90', '--positions', '1',
                 '--out', str(classifier)]) == 0
    assert main(['templates', '--models', str(models), '--out', str(templates),
                 '--views', '4']) == 0
    capsys.readouterr()
    out = tmp_path / 'o'
    assert main(['evaluate', '--models', str(models), '--dataset', str(data), '--oracle',
                 'none', '--classifier', str(classifier), '--templates', str(templates),
                 '--out', str(out)]) == 0
    assert 'pose skipped on 2 frames without depth' in capsys.readouterr().out
    report = json.loads((out / 'report.json').read_text())
    assert report['skipped']['pose_frames_without_depth'] == 2
    assert report['detection']['iou07_rate'] is not None
    # every target the localiser missed has a cause, from masks ray-cast at the truth
    breakdown = report['detection']['breakdown']
    missed = round(report['objects_gt'] * (1 - report['detection']['iou07_rate']))
    assert sum(breakdown['missed'].values()) == missed


def _square(size_m: float):
    """Two triangles: a square of side ``size_m`` in the object's z = 0 plane."""
    h = size_m / 2
    vertices = np.array([[-h, -h, 0], [h, -h, 0], [h, h, 0], [-h, h, 0]], float)
    return vertices, np.array([[0, 1, 2], [0, 2, 3]])


def test_visible_masks_are_ray_cast_where_the_set_has_none():
    vertices, faces = _square(0.04)
    models = {1: SimpleNamespace(vertices=vertices, faces=faces)}
    near, far = make_transform(np.eye(3), [0.0, 0, 0.4]), make_transform(np.eye(3),
                                                                         [0.02, 0, 0.5])
    intrinsics = CameraIntrinsics(100, 100, np.array([[100.0, 0, 50], [0, 100, 50], [0, 0, 1]]))
    image = BopImage('test', 1, 0, None, None, intrinsics, None,
                     [BopGroundTruth(1, T, None, None) for T in (near, far)])
    masked = with_visible_masks(image, models)
    front, back = (gt.mask for gt in masked.gt)
    assert front.sum() > 0 and back.sum() > 0 and not np.any(front & back)
    # the far square, 2 cm aside, shows only beyond the near one's edge
    assert back.sum() < 0.6 * (0.04 * 100 / 0.5) ** 2
    assert image.gt[0].mask is None                              # the input is left as it was
    assert with_visible_masks(masked, models) is masked         # masks present: unchanged
