import numpy as np
import pytest
from scipy.spatial import cKDTree

from tlessbot_ros.core.pose import PointBuckets


@pytest.mark.parametrize('radius', [0.002, 0.005, 0.01])
def test_nearest_within_equals_kdtree(radius):
    rng = np.random.default_rng(3)
    points = rng.uniform(-0.05, 0.05, (2000, 3))
    queries = np.concatenate([points[:300] + rng.normal(0, radius / 2, (300, 3)),
                              rng.uniform(-0.08, 0.08, (300, 3))])   # some outside the box
    buckets = PointBuckets.build(points, 0.01)
    dist, index = buckets.nearest(queries, radius)
    want_dist, want_index = cKDTree(points).query(queries, k=1, distance_upper_bound=radius)
    np.testing.assert_array_equal(np.isfinite(dist), np.isfinite(want_dist))
    assert np.isfinite(dist).sum() > 100 and (~np.isfinite(dist)).sum() > 100
    np.testing.assert_allclose(dist[np.isfinite(dist)], want_dist[np.isfinite(want_dist)],
                               rtol=1e-12)
    np.testing.assert_array_equal(index, want_index)
    np.testing.assert_array_equal(buckets.any_within(queries, radius), np.isfinite(want_dist))


def test_radius_is_strict_and_bounded_by_the_edge():
    buckets = PointBuckets.build(np.zeros((1, 3)), 0.01)
    dist, index = buckets.nearest(np.array([[0.005, 0.0, 0.0]]), 0.005)
    assert np.isinf(dist[0]) and index[0] == 1          # at exactly the radius: not a neighbour
    assert buckets.nearest(np.array([[0.004, 0.0, 0.0]]), 0.005)[1][0] == 0
    with pytest.raises(ValueError, match='bucket edge'):
        buckets.nearest(np.zeros((1, 3)), 0.02)


def test_empty_points_and_nan_queries():
    empty = PointBuckets.build(np.zeros((0, 3)), 0.01)
    dist, index = empty.nearest(np.zeros((2, 3)), 0.01)
    assert np.isinf(dist).all() and (index == 0).all()
    buckets = PointBuckets.build(np.zeros((1, 3)), 0.01)
    dist, index = buckets.nearest(np.array([[np.nan, 0.0, 0.0], [0.0, 0.0, 0.0]]), 0.01)
    assert np.isinf(dist[0]) and index[0] == 1 and dist[1] == 0.0


def test_any_within_is_the_nearest_test():
    """The early-exit test answers as ``isfinite(nearest)``, also at exactly the radius, on a
    grid of points (distances that equal the radius), for NaN queries and empty buckets."""
    rng = np.random.default_rng(4)
    grid = 0.002 * np.stack(np.meshgrid(*[np.arange(12)] * 3), -1).reshape(-1, 3)
    for points, edge in ((rng.uniform(-0.05, 0.05, (1500, 3)), 0.01), (grid, 0.004),
                         (np.zeros((0, 3)), 0.01)):
        buckets = PointBuckets.build(points, edge)
        queries = np.concatenate([rng.uniform(-0.06, 0.06, (400, 3)), grid[::7] + 0.002,
                                  [[np.nan, 0.0, 0.0]]])
        for radius in (0.001, 0.002, 0.004):
            if radius <= edge:
                np.testing.assert_array_equal(buckets.any_within(queries, radius),
                                              np.isfinite(buckets.nearest(queries, radius)[0]))


def test_a_cloud_metres_wide_gets_larger_buckets_and_the_same_answers():
    from tlessbot_ros.core.pose.buckets import MAX_BUCKETS

    # a real frame's wall taken for a part: 4 m wide in 1 mm buckets would need 10^10 of them
    rng = np.random.default_rng(5)
    points = np.concatenate([rng.uniform(0, 4, (3000, 3)), rng.uniform(0, 0.01, (300, 3))])
    buckets = PointBuckets.build(points, 0.001)
    assert np.prod(buckets.shape) <= MAX_BUCKETS and buckets.edge_m > 0.001
    queries = rng.uniform(0, 0.012, (200, 3))
    dist, index = buckets.nearest(queries, 0.001)
    want_dist, want_index = cKDTree(points).query(queries, k=1, distance_upper_bound=0.001)
    assert np.isfinite(dist).sum() > 20
    np.testing.assert_array_equal(index, want_index)
    np.testing.assert_array_equal(buckets.any_within(queries, 0.001), np.isfinite(want_dist))
