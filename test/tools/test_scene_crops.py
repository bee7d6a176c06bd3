"""The scene crops of ``tlessbot train --scenes``: the same for any number of workers; a share
of the scenes with stereo-like depth."""
from __future__ import annotations

import numpy as np
import pytest

from tlessbot_ros.core.recognise import HogParams, ShapeParams
from tlessbot_ros.tools.support.part_generator import generate_parts
from tlessbot_ros.tools.support.scene_crops import scene_features

pytestmark = pytest.mark.slow


@pytest.fixture(scope='module')
def models(tmp_path_factory):
    cad = tmp_path_factory.mktemp('cad')
    generate_parts(cad, ['bracket_short', 'tube'])
    models = tmp_path_factory.mktemp('models')
    for k, path in enumerate(sorted(cad.glob('*.stl')), start=1):   # obj_NN, as parts build
        (models / f'obj_{k:02d}.stl').write_bytes(path.read_bytes())
    return models


def test_workers_give_the_same_crops_in_the_same_order(models):
    options = dict(ids=None, scenes=10, seed=7)   # two chunks of work
    alone = scene_features(models, HogParams(), ShapeParams(), workers=1, **options)
    shared = scene_features(models, HogParams(), ShapeParams(), workers=2, **options)
    assert len(alone[1]) > 10 and set(alone[1]) == {1, 2}
    assert np.array_equal(alone[1], shared[1])
    assert np.array_equal(alone[0], shared[0], equal_nan=True)


def test_a_share_of_the_scenes_has_stereo_like_depth(models):
    options = dict(ids=None, scenes=4, seed=7, workers=1)
    plain = scene_features(models, HogParams(), ShapeParams(), **options)
    mixed = scene_features(models, HogParams(), ShapeParams(), smoothed_share=0.5, **options)
    assert np.array_equal(plain[1], mixed[1])   # the same scenes, the same parts seen
    # scenes 1 and 3 are smoothed: some of their parts' descriptors change, not all crops'
    same = np.all(np.isclose(plain[0], mixed[0], equal_nan=True), axis=1)
    assert 0 < int((~same).sum()) < len(same)
    # with the masks as they are, only the depth's shape values change, never the HOG
    kept = scene_features(models, HogParams(), ShapeParams(), smoothed_share=0.5, region_px=0,
                          **options)
    hog_dim = HogParams().feature_dim
    assert np.array_equal(plain[0][:, :hog_dim], kept[0][:, :hog_dim])
    assert not np.array_equal(plain[0][:, hog_dim:], kept[0][:, hog_dim:], equal_nan=True)
