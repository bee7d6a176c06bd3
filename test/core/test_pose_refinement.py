"""The pose stage's seams: a swapped Refiner, the cached model arrays, the RANSAC candidates."""
from __future__ import annotations

import numpy as np
import pytest

from tlessbot_ros.core.pose import (
    PoseEstimator,
    PoseParams,
    Refiner,
    TemplateDatabase,
    ransac_candidates,
)
from tlessbot_ros.data import DEFAULT_TEMPLATES


@pytest.fixture(scope='module')
def packaged():
    db = TemplateDatabase.load(DEFAULT_TEMPLATES)
    obj_id = sorted(db.objects)[0]
    T_world_camera = np.asarray(db.params['T_world_camera'], np.float64)
    points = db[obj_id].templates[0].points.astype(np.float64)
    return db, obj_id, T_world_camera, points


def test_model_arrays_are_float64_copies_made_once(packaged):
    db, obj_id, _, _ = packaged
    obj = db[obj_id]
    normals, points = obj.model_arrays_float64()
    assert normals.dtype == points.dtype == np.float64
    np.testing.assert_array_equal(points, obj.model_points)
    assert obj.model_arrays_float64()[1] is points
    subset_points, subset_normals = obj.model_subset(50)
    np.testing.assert_array_equal(subset_points, obj.model_points[:50])
    np.testing.assert_array_equal(subset_normals, obj.model_normals[:50])
    assert obj.model_subset(50)[0] is subset_points


def test_a_swapped_refiner_is_used_and_the_default_is_unchanged(packaged):
    db, obj_id, T_world_camera, points = packaged

    class Counting(Refiner):
        calls: list[str] = []

        def icp_batch(self, *args, **kwargs):
            self.calls.append('icp')
            return super().icp_batch(*args, **kwargs)

        def evaluate(self, *args, **kwargs):
            self.calls.append('evaluate')
            return super().evaluate(*args, **kwargs)

    params = PoseParams()
    swapped = PoseEstimator(db, params=params, refiner=Counting(params))
    result = swapped.estimate(points, obj_id, T_world_camera=T_world_camera, fallback=False)
    assert 'icp' in Counting.calls and 'evaluate' in Counting.calls
    default = PoseEstimator(db, params=params).estimate(points, obj_id,
                                                        T_world_camera=T_world_camera,
                                                        fallback=False)
    np.testing.assert_array_equal(result.best.T_camera_object, default.best.T_camera_object)
    assert result.best.score == default.best.score


def test_ransac_candidates_without_refinement_keep_the_paper_ranking(packaged):
    db, obj_id, _, points = packaged
    params = PoseParams(method='ransac', refine=False, ransac_max_iteration=200)
    timings: dict[str, float] = {}
    out = ransac_candidates(points, db[obj_id], timings, params=params,
                            refiner=Refiner(params), indices=[0, 1])
    assert [c.template_index for c in out] == [0, 1]
    assert all(c.coverage == 0.0 and c.method == 'ransac' for c in out)
    assert timings['features'] > 0
