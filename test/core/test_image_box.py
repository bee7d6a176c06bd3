"""A part's given box in box mode (issue 41, core/pose/image_box.py): the share of the box a
pose's projected model covers, and the table path weighing its poses by it."""
from __future__ import annotations

import numpy as np
import pytest

from tlessbot_ros.core.common import default_rig, make_transform, project_points
from tlessbot_ros.core.pose import (
    ImageBox,
    PoseCandidate,
    PoseEstimator,
    PoseParams,
    box_cover,
)
from tlessbot_ros.core.pose.building import build_object_templates

SIDE = default_rig()['side']


def _bar():
    """A bar 80 x 10 x 10 mm (8 vertices, 12 triangles), centred on its origin."""
    corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
    faces = [(0, 1, 3), (0, 3, 2), (4, 6, 7), (4, 7, 5), (0, 4, 5), (0, 5, 1),
             (2, 3, 7), (2, 7, 6), (0, 2, 6), (0, 6, 4), (1, 5, 7), (1, 7, 3)]
    return corners * [0.04, 0.005, 0.005], np.array(faces, np.int32)


@pytest.fixture(scope='module')
def bar():
    v, f = _bar()
    return build_object_templates(1, v, f, [(make_transform(np.eye(3), [0, 0, 0.005]), 1.0)],
                                  intrinsics=SIDE.intrinsics, T_world_camera=SIDE.T_world_camera)


def _extent(obj, T):
    """(x, y, w, h) pixel box of the model's samples at pose T (camera frame)."""
    uv = project_points((obj.model_points @ T[:3, :3].T + T[:3, 3]).astype(np.float64),
                        SIDE.intrinsics.K)
    lo, hi = np.floor(uv.min(axis=0) + 0.5), np.floor(uv.max(axis=0) + 0.5)
    return int(lo[0]), int(lo[1]), int(hi[0] - lo[0] + 1), int(hi[1] - lo[1] + 1)


def _on_table(yaw_deg, x=0.0, y=0.0):
    c, s = np.cos(np.radians(yaw_deg)), np.sin(np.radians(yaw_deg))
    return SIDE.T_camera_world @ make_transform([[c, -s, 0], [s, c, 0], [0, 0, 1]],
                                                [x, y, 0.005])


def test_a_pose_covers_its_own_box_and_half_of_a_box_twice_as_wide(bar):
    T = _on_table(0.0)
    x, y, w, h = _extent(bar, T)
    box = ImageBox((x, y, w, h), SIDE.intrinsics.K)
    assert box_cover(T, bar, box)[0] == pytest.approx(1.0, abs=0.03)
    wider = ImageBox((x, y, 2 * w, h), SIDE.intrinsics.K)
    assert box_cover(T, bar, wider)[0] == pytest.approx(0.5, abs=0.03)
    away = ImageBox((x + 3 * w, y, w, h), SIDE.intrinsics.K)
    assert box_cover(T, bar, away)[0] == 0.0
    behind = T.copy()
    behind[2, 3] = -behind[2, 3]
    covers = box_cover(np.stack([T, behind]), bar, box)
    assert covers.shape == (2,) and covers[1] == 0.0


def test_a_box_needs_a_size_and_a_camera_matrix():
    with pytest.raises(ValueError, match='w, h >= 1'):
        ImageBox((0, 0, 0, 5), SIDE.intrinsics.K)
    with pytest.raises(ValueError, match='3x3'):
        ImageBox((0, 0, 5, 5), np.eye(4))


def test_without_a_box_the_score_is_fitness_and_coverage():
    candidate = PoseCandidate(np.eye(4), 0.8, 0.001, 0.5)
    assert candidate.box_cover == 1.0 and candidate.score == pytest.approx(0.8 + 0.3 * 0.5)
    candidate.box_cover = 0.5
    assert candidate.score == pytest.approx(0.5 * (0.8 + 0.3 * 0.5))
    assert candidate.box_fitness == pytest.approx(0.4)


def test_the_box_picks_the_part_that_spans_it_over_a_neighbour_with_more_points(bar):
    """Two bars in one box: the box's own bar spans it, its middle hidden (2 x 15 mm of its 80
    seen), and a neighbour 40 mm away shows 40 mm. Without the box the fit lands between them
    (placed at the points' centroid); with it, on the bar that spans the box."""
    rng = np.random.default_rng(0)
    own_T, neighbour_T = _on_table(40.0), _on_table(40.0, 0.0, 0.04)
    samples = bar.model_points.astype(np.float64)
    ends = samples[np.abs(samples[:, 0]) > 0.025]                      # 2 x 15 mm of 80
    middle = samples[np.abs(samples[:, 0]) < 0.02]                     # 40 mm of 80
    points = np.concatenate([ends @ own_T[:3, :3].T + own_T[:3, 3],
                             middle @ neighbour_T[:3, :3].T + neighbour_T[:3, 3]])
    points += rng.normal(0, 0.0003, points.shape)
    box = ImageBox(_extent(bar, own_T), SIDE.intrinsics.K)
    estimator = PoseEstimator(None, params=PoseParams(fallback=False))   # type: ignore[arg-type]
    estimator.database = {1: bar}                                    # type: ignore[assignment]

    def centre_gap(result):
        return np.linalg.norm(result.best.T_camera_object[:3, 3] - own_T[:3, 3])

    blind = estimator.estimate(points, 1, T_world_camera=SIDE.T_world_camera)
    boxed = estimator.estimate(points, 1, T_world_camera=SIDE.T_world_camera, box=box)
    assert centre_gap(blind) > 0.01            # pulled towards the neighbour, 40 mm away
    assert centre_gap(boxed) < 0.003 and boxed.best.box_cover > 0.9
