"""The pose stage on real-camera depth (issue 40): classes compared at one tolerance, the
classifier overruled only by a clear margin, Gauss-Newton steps bounded, depth ramps found."""
from types import SimpleNamespace

import numpy as np
import pytest

from tlessbot_ros.core.common import default_rig, make_transform
from tlessbot_ros.core.frame import Detection, PartJob
from tlessbot_ros.core.params import FitParams
from tlessbot_ros.core.part_fit import fit_part
from tlessbot_ros.core.pose import PoseCandidate, PoseResult, Refiner, steep_pixels
from tlessbot_ros.core.pose.building import build_object_templates
from tlessbot_ros.core.pose.grid_kernels import MAX_STEP_RAD, _limit_step

SIDE = default_rig()['side']


def _box(size):
    """A closed box mesh (8 vertices, 12 triangles) of ``size`` (m) with a corner at 0."""
    corners = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], float)
    faces = [(0, 1, 3), (0, 3, 2), (4, 6, 7), (4, 7, 5), (0, 4, 5), (0, 5, 1),
             (2, 3, 7), (2, 7, 6), (0, 2, 6), (0, 6, 4), (1, 5, 7), (1, 7, 3)]
    return corners * np.asarray(size, float), np.array(faces, np.int32)


@pytest.fixture(scope='module')
def small_and_large():
    """A nut-sized box (10 x 9 x 6 mm, voxel 0.4 mm) and a key-sized one (170 x 30 x 20 mm)."""
    objects = []
    for obj_id, size in ((1, (0.010, 0.009, 0.006)), (2, (0.170, 0.030, 0.020))):
        v, f = _box(size)
        objects.append(build_object_templates(obj_id, v, f, [(np.eye(4), 1.0)],
                                              intrinsics=SIDE.intrinsics,
                                              T_world_camera=SIDE.T_world_camera))
    return objects


def test_classes_are_compared_at_one_tolerance(small_and_large):
    small, large = small_and_large
    rng = np.random.default_rng(3)
    # the small box's top face (z = 6 mm) seen with 1 mm of depth noise
    top = np.column_stack([rng.uniform(0, 0.010, 400), rng.uniform(0, 0.009, 400),
                           0.006 + rng.normal(0, 0.001, 400)])
    at_small = np.eye(4)
    at_large = make_transform(np.eye(3), [-0.05, -0.01, -0.014])   # its top face there too
    refiner = Refiner()
    own = [refiner.evaluate(top, o, T, method='table').fitness
           for o, T in ((small, at_small), (large, at_large))]
    common = [refiner.surface_fit(top, o, T, inlier_m=0.003)[0]
              for o, T in ((small, at_small), (large, at_large))]
    assert own[0] < 0.6 < 0.9 < own[1]           # at their own voxels the large box wins
    assert common[0] > 0.9 and abs(common[0] - common[1]) < 0.05   # at one tolerance: equal
    away = top + [0, 0, 0.006]
    assert refiner.surface_fit(away, small, at_small, inlier_m=0.003)[0] < 0.1
    assert refiner.surface_fit(top[:0], small, at_small, inlier_m=0.003) == (0.0, np.inf)


class _Estimator:
    """Fitness per class, as an estimator would find it (no table frame: no polish)."""

    def __init__(self, fitness):
        self.fitness = fitness
        self.params = SimpleNamespace(fallback=False)
        self.database = {i: SimpleNamespace(lookalikes=()) for i in (1, 2, 3)}   # no twins

    def estimate(self, points, obj_id, **options):
        if obj_id not in self.fitness:
            return PoseResult(obj_id, None, None, 0)
        best = PoseCandidate(np.eye(4), self.fitness[obj_id], 0.001, 0.5, 'table')
        return PoseResult(obj_id, best, None, len(points))


@pytest.mark.parametrize('fitness, named', [
    ({1: 0.60, 2: 0.63}, 1),                   # within the margin: the classifier's class
    ({1: 0.60, 2: 0.70}, 2),                   # clearly better: overruled
    ({1: 0.60, 2: 0.62, 3: 0.70}, 3),          # the clear winner among the others
    ({2: 0.40, 3: 0.43}, 3),                   # the first not fitted: the others by fit alone
])
def test_the_classifier_is_overruled_only_by_a_clear_margin(fitness, named):
    job = PartJob(Detection(1, 1, 'side', (0, 0, 1, 1)), np.zeros((50, 3)), (1, 2, 3), None)
    params = FitParams(verify_inlier_m=0.0, verify_rmse_weight=0.0, verify_overrule_margin=0.05)
    fit_part(_Estimator(fitness), params, job)
    assert job.detection.obj_id == named
    assert job.detection.pose.fitness == fitness[named]


def test_gauss_newton_steps_are_bounded():
    step = np.array([0.5, 0.0, 0.0, 0.03, 0.04, 0.0])
    _limit_step(step, False, 0.01)
    assert np.linalg.norm(step[3:]) <= 0.01 + 1e-12
    assert np.linalg.norm(step[:3]) <= MAX_STEP_RAD + 1e-12
    small = np.array([0.01, 0.002, 0.001])
    kept = small.copy()
    _limit_step(kept, True, 0.01)
    assert np.array_equal(kept, small)


def test_depth_ramps_and_holes_are_steep_flat_ground_is_not():
    depth = np.full((20, 40), 0.40, np.float32)
    depth[:, 20:] = 0.39                     # a 10 mm step, smoothed into a 3-pixel ramp
    depth[:, 19] = 0.3975
    depth[:, 20] = 0.3925
    depth[5, 5] = np.nan
    steep = steep_pixels(depth, 600.0, 75.0)
    assert steep[:, 19:21].all() and steep[5, 4] and steep[4, 5]
    assert not steep[10, 8:16].any() and not steep[10, 24:36].any()
    tilted = 0.4 + 0.0005 * np.arange(40, dtype=np.float32)[None].repeat(20, 0)  # 37 deg
    assert not steep_pixels(tilted, 600.0, 75.0)[2:-2, 2:-2].any()
