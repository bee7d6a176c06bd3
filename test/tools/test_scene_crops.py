"""The scene crops of ``tlessbot train --scenes``: the same for any number of workers."""
from __future__ import annotations

import numpy as np
import pytest

from tlessbot_ros.core.recognise import HogParams, ShapeParams
from tlessbot_ros.tools.support.part_generator import generate_parts
from tlessbot_ros.tools.support.scene_crops import scene_features

pytestmark = pytest.mark.slow


def test_workers_give_the_same_crops_in_the_same_order(tmp_path):
    cad = tmp_path / 'cad'
    generate_parts(cad, ['bracket_short', 'tube'])
    models = tmp_path / 'models'
    models.mkdir()
    for k, path in enumerate(sorted(cad.glob('*.stl')), start=1):   # obj_NN, as parts build
        (models / f'obj_{k:02d}.stl').write_bytes(path.read_bytes())
    options = dict(ids=None, scenes=10, seed=7)   # two chunks of work
    alone = scene_features(models, HogParams(), ShapeParams(), workers=1, **options)
    shared = scene_features(models, HogParams(), ShapeParams(), workers=2, **options)
    assert len(alone[1]) > 10 and set(alone[1]) == {1, 2}
    assert np.array_equal(alone[1], shared[1])
    assert np.array_equal(alone[0], shared[0], equal_nan=True)
