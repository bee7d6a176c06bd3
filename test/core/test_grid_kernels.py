"""The numba grid kernels compute what the plain numpy formulation of the table path does."""
from __future__ import annotations

import numpy as np
import pytest

from tlessbot_ros.core.pose import NearestGrid, inlier_fraction, normal_equations, truncated_cost


@pytest.fixture(scope='module')
def setup():
    rng = np.random.default_rng(3)
    model = rng.normal(size=(400, 3)) * [0.03, 0.02, 0.01]
    normals = rng.normal(size=(400, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    grid = NearestGrid.build(model, 0.002, margin_m=0.01)
    K = 5
    angles = rng.uniform(-0.3, 0.3, size=(K, 3))
    T = np.tile(np.eye(4), (K, 1, 1))
    for k, (a, b, c) in enumerate(angles):
        ca, sa, cb, sb, cc, sc = np.cos(a), np.sin(a), np.cos(b), np.sin(b), np.cos(c), np.sin(c)
        Rx = np.array([[1, 0, 0], [0, ca, -sa], [0, sa, ca]])
        Ry = np.array([[cb, 0, sb], [0, 1, 0], [-sb, 0, cb]])
        Rz = np.array([[cc, -sc, 0], [sc, cc, 0], [0, 0, 1]])
        T[k, :3, :3] = Rz @ Ry @ Rx
        T[k, :3, 3] = rng.normal(scale=0.005, size=3)
    # scene: model points seen under the first pose, with noise, plus far-away clutter
    points = model[:250] @ T[0, :3, :3].T + T[0, :3, 3] + rng.normal(scale=0.001, size=(250, 3))
    points = np.vstack([points, rng.uniform(-0.2, 0.2, size=(20, 3))])
    return model, normals, grid, T, points


def _reference(T, points, grid, model, normals, max_d, planar):
    """The numpy formulation the kernels replaced (K, N, 3 temporaries)."""
    R, t = T[:, :3, :3], T[:, :3, 3]
    q = (points[None] - t[:, None, :]) @ R
    index, _ = grid.lookup(q)
    ok = index >= 0
    idx = np.where(ok, index, 0)
    ok &= np.linalg.norm(q - model[idx], axis=-1) < max_d
    Rt = np.transpose(R, (0, 2, 1))
    m = model[idx] @ Rt + t[:, None, :]
    n = normals[idx] @ Rt
    r = np.sum(n * (points[None] - m), axis=-1)
    arm = m - t[:, None, :]
    if planar:
        J = np.stack([arm[..., 0] * n[..., 1] - arm[..., 1] * n[..., 0],
                      n[..., 0], n[..., 1]], axis=-1)
    else:
        J = np.concatenate([np.cross(arm, n), n], axis=-1)
    w = ok.astype(float)
    return (np.einsum('kn,kni,knj->kij', w, J, J), np.einsum('kn,kni,kn->ki', w, J, r),
            ok.sum(axis=1), q, index)


@pytest.mark.parametrize('planar', [False, True])
def test_normal_equations_match_numpy(setup, planar):
    model, normals, grid, T, points = setup
    A_ref, b_ref, count_ref, _, _ = _reference(T, points, grid, model, normals, 0.004, planar)
    A, b, count = normal_equations(np.ascontiguousarray(T[:, :3, :3]),
                                   np.ascontiguousarray(T[:, :3, 3]), points, grid.origin,
                                   grid.spacing, grid.index, model, normals, 0.004, planar)
    assert count_ref.min() > 50      # the test exercises real correspondences
    np.testing.assert_array_equal(count, count_ref)
    np.testing.assert_allclose(A, A_ref, rtol=1e-9, atol=1e-15)
    np.testing.assert_allclose(b, b_ref, rtol=1e-9, atol=1e-15)


def test_cost_and_fitness_match_numpy(setup):
    model, normals, grid, T, points = setup
    R, t = np.ascontiguousarray(T[:, :3, :3]), np.ascontiguousarray(T[:, :3, 3])
    _, _, _, q, index = _reference(T, points, grid, model, normals, 0.004, False)
    tau = 0.003
    _, dist = grid.lookup(q, outside=tau)
    np.testing.assert_allclose(
        truncated_cost(R, t, points, grid.origin, grid.spacing, grid.distance, tau),
        np.minimum(dist, tau).mean(axis=1), rtol=1e-6)   # the grid holds float32 distances
    d = np.linalg.norm(q - model[np.maximum(index, 0)], axis=-1)
    expected = ((index >= 0) & (d < 0.002)).mean(axis=1)
    fitness = inlier_fraction(R, t, points, grid.origin, grid.spacing, grid.index, model, 0.002)
    np.testing.assert_allclose(fitness, expected)
    assert fitness[0] > 0.5 > fitness.min()   # the true pose fits, the others less


@pytest.mark.parametrize('planar', [False, True])
def test_gauss_newton_equals_the_python_loop(setup, planar):
    """The fused iterations equal one normal_equations call, a numpy solve and the update per
    iteration, and a 6-DOF run converges towards the pose the scene was drawn from."""
    from tlessbot_ros.core.pose import gauss_newton
    from tlessbot_ros.core.pose.hypotheses import rodrigues, rotations_about_z

    model, normals, grid, T, points = setup
    start = T.copy()
    start[:, :3, 3] = T[0, :3, 3] + 0.002
    max_d = np.array([0.008, 0.008, 0.004, 0.004])
    R, t = start[:, :3, :3].copy(), start[:, :3, 3].copy()
    for d in max_d:
        A, b, count = normal_equations(R, t, points, grid.origin, grid.spacing, grid.index,
                                       model, normals, d, planar)
        size = 3 if planar else 6
        delta = np.linalg.solve(A + 1e-9 * np.eye(size), b[..., None])[..., 0]
        delta[count < 6] = 0.0
        if planar:
            R = rotations_about_z(delta[:, 0]) @ R
            t = t + np.column_stack([delta[:, 1], delta[:, 2], np.zeros(len(t))])
        else:
            R = rodrigues(delta[:, :3]) @ R
            t = t + delta[:, 3:]
    R_fused, t_fused = gauss_newton(np.ascontiguousarray(start[:, :3, :3]),
                                    np.ascontiguousarray(start[:, :3, 3]), points, grid.origin,
                                    grid.spacing, grid.index, model, normals, max_d, planar, 0.0)
    np.testing.assert_allclose(R_fused, R, atol=1e-9)
    np.testing.assert_allclose(t_fused, t, atol=1e-9)
    if not planar:
        assert np.linalg.norm(t_fused[0] - T[0, :3, 3]) < np.linalg.norm(start[0, :3, 3]
                                                                         - T[0, :3, 3])



def test_each_pose_of_a_batch_ends_where_it_would_alone(setup):
    """With stop_below, a pose stops on its own small update (until the correspondence
    distance changes), so a batch gives every pose what a run of that pose alone gives; the
    batch once stopped only when all had converged, and at the first distance if they had."""
    from tlessbot_ros.core.pose import gauss_newton

    model, normals, grid, T, points = setup
    start = T.copy()
    start[:, :3, 3] = T[0, :3, 3] + 0.002
    start[0] = T[0]                                  # converges at once
    max_d = np.repeat([0.008, 0.004], 8)
    args = (points, grid.origin, grid.spacing, grid.index, model, normals, max_d, False, 1e-6)
    R, t = gauss_newton(np.ascontiguousarray(start[:, :3, :3]),
                        np.ascontiguousarray(start[:, :3, 3]), *args)
    for k in range(len(start)):
        R_k, t_k = gauss_newton(np.ascontiguousarray(start[k:k + 1, :3, :3]),
                                np.ascontiguousarray(start[k:k + 1, :3, 3]), *args)
        np.testing.assert_allclose(R[k], R_k[0], atol=1e-12)
        np.testing.assert_allclose(t[k], t_k[0], atol=1e-12)
    # the second distance still refines a pose that stopped in the first
    R_first, t_first = gauss_newton(np.ascontiguousarray(start[:1, :3, :3]),
                                    np.ascontiguousarray(start[:1, :3, 3]), points,
                                    grid.origin, grid.spacing, grid.index, model, normals,
                                    max_d[:8], False, 1e-6)
    A, b, count = normal_equations(R_first, t_first, points, grid.origin, grid.spacing,
                                   grid.index, model, normals, 0.004, False)
    delta = np.linalg.solve(A[0] + 1e-9 * np.eye(6), b[0])
    assert np.abs(delta).max() >= 1e-6              # the closer distance has work to do
    assert not np.allclose(t[0], t_first[0], rtol=0, atol=1e-9)


def _visible_reference(points_c, normals_c, cell_rad, depth_tolerance_m):
    """The numpy z-buffer the kernel replaced."""
    facing = np.sum(normals_c * points_c, axis=1) < 0
    z = points_c[:, 2]
    ok = facing & (z > 1e-6)
    if not ok.any():
        return ok
    uv = np.floor(points_c[ok, :2] / z[ok, None] / cell_rad).astype(np.int64)
    uv -= uv.min(axis=0)
    key = uv[:, 0] * (uv[:, 1].max() + 1) + uv[:, 1]
    nearest = np.full(key.max() + 1, np.inf)
    np.minimum.at(nearest, key, z[ok])
    visible = np.zeros(len(points_c), bool)
    visible[np.flatnonzero(ok)] = z[ok] <= nearest[key] + depth_tolerance_m
    return visible


def test_self_visible_equals_the_numpy_z_buffer(setup):
    from tlessbot_ros.core.pose import self_visible

    model, normals, _, T, _ = setup
    for k in range(len(T)):
        points = model @ T[k, :3, :3].T + T[k, :3, 3] + [0.0, 0.0, 0.6]   # in front of a camera
        rotated = normals @ T[k, :3, :3].T
        got = self_visible(points, rotated, 0.003, 0.004)
        want = _visible_reference(points, rotated, 0.003, 0.004)
        np.testing.assert_array_equal(got, want)
        assert 0 < got.sum() < len(got)                  # some seen, some back-facing or hidden
    behind = model - [0.0, 0.0, 1.0]                     # all behind the camera: none visible
    assert not self_visible(behind, normals, 0.003, 0.004).any()
