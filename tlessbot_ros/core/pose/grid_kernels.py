"""Fused loops of the table-path pose search over a nearest-sample grid (numba).

The table path scores and refines K poses of one object against N scene points through a
:class:`~tlessbot_ros.core.pose.NearestGrid`. Written with numpy, each step builds several
(K, N, 3) temporaries and spends most of its time in small-array overhead; these kernels make
one pass per pose and point, without temporaries. They compute exactly what the numpy
formulation does (up to summation order): tests compare the two. They release the GIL, so a
node's executor thread can take messages meanwhile.

Common arguments:
    R: (K, 3, 3) rotations and t: (K, 3) translations of T_frame_object, float64.
    points: (N, 3) points in that frame, metres.
    origin, spacing, index_grid / distance_grid: the NearestGrid (cell (i, j, k) covers
        origin + [i, i+1) * spacing on x, and so on).
    model, normals: (M, 3) model surface samples and unit normals, object frame.

Reference: Y. Chen, G. Medioni, "Object modelling by registration of multiple range images",
Image and Vision Computing 10(3), 1992 (point-to-plane normal equations).
"""
from __future__ import annotations

import numpy as np
from numba import njit

MAX_STEP_RAD = 0.2   # the largest rotation of one Gauss-Newton step (rad), see _limit_step


@njit(cache=True, inline='always')
def _cell(qx: float, qy: float, qz: float, origin: np.ndarray, spacing: float,
          shape: tuple[int, ...]) -> tuple[int, int, int]:
    """Grid cell of an object-frame point, or (-1, 0, 0) outside."""
    cx = int(np.floor((qx - origin[0]) / spacing))
    cy = int(np.floor((qy - origin[1]) / spacing))
    cz = int(np.floor((qz - origin[2]) / spacing))
    if cx < 0 or cy < 0 or cz < 0 or cx >= shape[0] or cy >= shape[1] or cz >= shape[2]:
        return -1, 0, 0
    return cx, cy, cz


@njit(cache=True, inline='always')
def _to_object(R: np.ndarray, t: np.ndarray, k: int, px: float, py: float,
               pz: float) -> tuple[float, float, float]:
    """R_k^T (p - t_k)."""
    dx, dy, dz = px - t[k, 0], py - t[k, 1], pz - t[k, 2]
    return (R[k, 0, 0] * dx + R[k, 1, 0] * dy + R[k, 2, 0] * dz,
            R[k, 0, 1] * dx + R[k, 1, 1] * dy + R[k, 2, 1] * dz,
            R[k, 0, 2] * dx + R[k, 1, 2] * dy + R[k, 2, 2] * dz)


@njit(cache=True, inline='always')
def _match(R: np.ndarray, t: np.ndarray, k: int, px: float, py: float, pz: float,
           origin: np.ndarray, spacing: float, index_grid: np.ndarray, model: np.ndarray,
           limit: float) -> tuple[int, float, float, float]:
    """The grid-nearest model sample of point p under pose k, if closer than sqrt(limit):
    (its index j, the object-frame point q - m) or (-1, 0, 0, 0)."""
    qx, qy, qz = _to_object(R, t, k, px, py, pz)
    cx, cy, cz = _cell(qx, qy, qz, origin, spacing, index_grid.shape)
    if cx < 0:
        return -1, 0.0, 0.0, 0.0
    j = index_grid[cx, cy, cz]
    ex, ey, ez = qx - model[j, 0], qy - model[j, 1], qz - model[j, 2]
    if ex * ex + ey * ey + ez * ez >= limit:
        return -1, 0.0, 0.0, 0.0
    return j, ex, ey, ez


@njit(cache=True, nogil=True)
def truncated_cost(R: np.ndarray, t: np.ndarray, points: np.ndarray, origin: np.ndarray,
                   spacing: float, distance_grid: np.ndarray, tau: float) -> np.ndarray:
    """(K,) mean over the points of min(grid distance to the model, tau); tau outside."""
    K, N = R.shape[0], points.shape[0]
    shape = distance_grid.shape
    cost = np.empty(K)
    for k in range(K):
        total = 0.0
        for i in range(N):
            qx, qy, qz = _to_object(R, t, k, points[i, 0], points[i, 1], points[i, 2])
            cx, cy, cz = _cell(qx, qy, qz, origin, spacing, shape)
            d = tau if cx < 0 else min(float(distance_grid[cx, cy, cz]), tau)
            total += d
        cost[k] = total / max(N, 1)
    return cost


@njit(cache=True, nogil=True)
def inlier_fraction(R: np.ndarray, t: np.ndarray, points: np.ndarray, origin: np.ndarray,
                    spacing: float, index_grid: np.ndarray, model: np.ndarray,
                    inlier_m: float) -> np.ndarray:
    """(K,) fraction of points closer than inlier_m to their grid-nearest model sample."""
    K, N = R.shape[0], points.shape[0]
    fraction = np.empty(K)
    limit = inlier_m * inlier_m
    for k in range(K):
        count = 0
        for i in range(N):
            j, _, _, _ = _match(R, t, k, points[i, 0], points[i, 1], points[i, 2], origin,
                                spacing, index_grid, model, limit)
            if j >= 0:
                count += 1
        fraction[k] = count / max(N, 1)
    return fraction


@njit(cache=True, nogil=True)
def normal_equations(R: np.ndarray, t: np.ndarray, points: np.ndarray, origin: np.ndarray,
                     spacing: float, index_grid: np.ndarray, model: np.ndarray,
                     normals: np.ndarray, max_d: float,
                     planar: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Point-to-plane Gauss-Newton normal equations of K poses.

    For every point whose grid-nearest model sample lies within ``max_d``: residual
    r = n . (p - (R m + t)) with n = R n_model, and the Jacobian row of a left increment
    about the object origin: [ (R m) x n, n ] (6-DOF), or in the plane
    [ (R m)_x n_y - (R m)_y n_x, n_x, n_y ] (yaw about the vertical, x, y) when ``planar``.

    Returns:
        A: (K, D, D) sum of J J^T, b: (K, D) sum of J r (D = 3 planar, else 6), and
        count: (K,) points used.
    """
    active = np.ones(R.shape[0], np.bool_)
    if planar:
        return _planar_equations(R, t, points, origin, spacing, index_grid, model, normals,
                                 max_d, active)
    return _full_equations(R, t, points, origin, spacing, index_grid, model, normals, max_d,
                           active)


@njit(cache=True, nogil=True)
def _planar_equations(R: np.ndarray, t: np.ndarray, points: np.ndarray, origin: np.ndarray,
                      spacing: float, index_grid: np.ndarray, model: np.ndarray,
                      normals: np.ndarray, max_d: float,
                      active: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`normal_equations` in the plane (D = 3), of the poses where ``active`` (K,) is
    True (zeros elsewhere)."""
    K, N = R.shape[0], points.shape[0]
    D = 3
    A = np.zeros((K, D, D))
    b = np.zeros((K, D))
    count = np.zeros(K, np.int64)
    J = np.empty(D)
    limit = max_d * max_d
    for k in range(K):
        if not active[k]:
            continue
        for i in range(N):
            px, py, pz = points[i, 0], points[i, 1], points[i, 2]
            j, _, _, _ = _match(R, t, k, px, py, pz, origin, spacing, index_grid, model, limit)
            if j < 0:
                continue
            mx, my, mz = model[j, 0], model[j, 1], model[j, 2]
            # arm = R m (the model point about the object origin), n = R n_model
            ax = R[k, 0, 0] * mx + R[k, 0, 1] * my + R[k, 0, 2] * mz
            ay = R[k, 1, 0] * mx + R[k, 1, 1] * my + R[k, 1, 2] * mz
            az = R[k, 2, 0] * mx + R[k, 2, 1] * my + R[k, 2, 2] * mz
            ux, uy, uz = normals[j, 0], normals[j, 1], normals[j, 2]
            nx = R[k, 0, 0] * ux + R[k, 0, 1] * uy + R[k, 0, 2] * uz
            ny = R[k, 1, 0] * ux + R[k, 1, 1] * uy + R[k, 1, 2] * uz
            nz = R[k, 2, 0] * ux + R[k, 2, 1] * uy + R[k, 2, 2] * uz
            r = (nx * (px - t[k, 0] - ax) + ny * (py - t[k, 1] - ay)
                 + nz * (pz - t[k, 2] - az))
            J[0] = ax * ny - ay * nx
            J[1] = nx
            J[2] = ny
            for a in range(D):
                b[k, a] += J[a] * r
                for c in range(a, D):
                    A[k, a, c] += J[a] * J[c]
            count[k] += 1
        for a in range(D):
            for c in range(a):
                A[k, a, c] = A[k, c, a]
    return A, b, count


@njit(cache=True, nogil=True)
def _full_equations(R: np.ndarray, t: np.ndarray, points: np.ndarray, origin: np.ndarray,
                    spacing: float, index_grid: np.ndarray, model: np.ndarray,
                    normals: np.ndarray, max_d: float,
                    active: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`normal_equations` in 6-DOF (D = 6) of the poses where ``active`` (K,) is True
    (zeros elsewhere), summed in the object frame.

    The camera-frame row [ (R m) x (R n), R n ] is B j with j = [ m x n, n ] (object frame)
    and B = diag(R, R), so A = B (sum j j^T) B^T and b = B (sum j r): the sums need no
    rotation per point, one per pose at the end (rotating every row was the 6-DOF ICP's main
    cost; equal up to rounding; docs/bench/code-figures.md)."""
    K, N = R.shape[0], points.shape[0]
    A = np.zeros((K, 6, 6))
    b = np.zeros((K, 6))
    count = np.zeros(K, np.int64)
    A_o = np.empty((6, 6))
    b_o = np.empty(6)
    J = np.empty(6)
    limit = max_d * max_d
    for k in range(K):
        if not active[k]:
            continue
        A_o[:] = 0.0
        b_o[:] = 0.0
        for i in range(N):
            j, ex, ey, ez = _match(R, t, k, points[i, 0], points[i, 1], points[i, 2], origin,
                                   spacing, index_grid, model, limit)
            if j < 0:
                continue
            mx, my, mz = model[j, 0], model[j, 1], model[j, 2]
            ux, uy, uz = normals[j, 0], normals[j, 1], normals[j, 2]
            # n . (p - t - R m) = n_model . (q - m): the residual needs no rotation either
            r = ux * ex + uy * ey + uz * ez
            J[0] = my * uz - mz * uy
            J[1] = mz * ux - mx * uz
            J[2] = mx * uy - my * ux
            J[3] = ux
            J[4] = uy
            J[5] = uz
            for a in range(6):
                b_o[a] += J[a] * r
                for c in range(a, 6):
                    A_o[a, c] += J[a] * J[c]
            count[k] += 1
        for a in range(6):
            for c in range(a):
                A_o[a, c] = A_o[c, a]
        # A = B A_o B^T, b = B b_o; B's blocks are R (rows 0-2 and 3-5)
        for a in range(6):
            ra, oa = a % 3, (a // 3) * 3
            for c in range(6):
                rc, oc = c % 3, (c // 3) * 3
                s = 0.0
                for u in range(3):
                    for v in range(3):
                        s += R[k, ra, u] * A_o[oa + u, oc + v] * R[k, rc, v]
                A[k, a, c] = s
            s = 0.0
            for u in range(3):
                s += R[k, ra, u] * b_o[oa + u]
            b[k, a] = s
    return A, b, count


@njit(cache=True, nogil=True)
def gauss_newton(R: np.ndarray, t: np.ndarray, points: np.ndarray, origin: np.ndarray,
                 spacing: float, index_grid: np.ndarray, model: np.ndarray,
                 normals: np.ndarray, max_d: np.ndarray, planar: bool,
                 stop_below: float) -> tuple[np.ndarray, np.ndarray]:
    """Point-to-plane Gauss-Newton iterations of K poses (the loop around
    :func:`normal_equations`), without returning to Python between iterations.

    Each iteration solves (A + 1e-9 I) delta = b per pose (delta = 0 for a pose with fewer than
    6 points in range) and applies it as a left increment about the object origin:
    6-DOF: R <- Rodrigues(delta[:3]) R, t <- t + delta[3:];
    planar: R <- Rz(delta[0]) R, t[:2] <- t[:2] + delta[1:3].

    Args:
        max_d: (I,) correspondence distance of each of the I iterations, metres.
        stop_below: a pose whose update has no component reaching this (rad, m), or that has
            fewer than 6 points in range, is left as it is until the correspondence distance
            changes (0: every pose runs all I). Each pose then ends where it would alone,
            and costs only its own steps: stopping the batch once every pose had settled
            ran nearly every polish step (some poses never settle: 2-cycles between grid
            correspondences, free turns about a symmetry axis) and skipped the closer
            distance when all settled at the first (docs/bench/code-figures.md).

    Returns:
        (R, t) refined copies.
    """
    R = R.copy()
    t = t.copy()
    K = R.shape[0]
    D = 3 if planar else 6
    eye = np.eye(D)
    active = np.ones(K, np.bool_)
    for it in range(max_d.shape[0]):
        if it > 0 and max_d[it] != max_d[it - 1]:
            active[:] = True    # new correspondences: every pose may move again
        elif not active.any():
            continue
        if planar:
            A, b, count = _planar_equations(R, t, points, origin, spacing, index_grid, model,
                                            normals, max_d[it], active)
        else:
            A, b, count = _full_equations(R, t, points, origin, spacing, index_grid, model,
                                          normals, max_d[it], active)
        for k in range(K):
            if not active[k]:
                continue
            if count[k] < 6:
                # no update, and none later at this distance (the same correspondences)
                active[k] = stop_below <= 0.0
                continue
            delta = np.linalg.solve(A[k] + 1e-9 * eye, b[k])
            _limit_step(delta, planar, max_d[it])
            largest = 0.0
            for a in range(D):
                largest = max(largest, abs(delta[a]))
            if planar:
                step = _rz_matrix(delta[0])
                t[k, 0] += delta[1]
                t[k, 1] += delta[2]
            else:
                step = _rodrigues_matrix(delta[0], delta[1], delta[2])
                t[k, 0] += delta[3]
                t[k, 1] += delta[4]
                t[k, 2] += delta[5]
            R[k] = step @ R[k]
            if largest < stop_below:
                active[k] = False
    return R, t


@njit(cache=True, inline='always')
def _limit_step(delta: np.ndarray, planar: bool, max_d: float) -> None:
    """Scale a Gauss-Newton step in place so that its translation stays within ``max_d`` (m)
    and its rotation within :data:`MAX_STEP_RAD`.

    Every correspondence lies within ``max_d``, so a converging step is shorter; a longer
    one comes from a direction the points do not constrain (a thin rod or a tube seen as a
    strip of its top on real depth, the ends cut off by the table clearance: free along and
    about its axis), where the undamped solve runs off and leaves no point in range."""
    r0 = 1 if planar else 3
    rot = 0.0
    for a in range(r0):
        rot += delta[a] * delta[a]
    move = 0.0
    for a in range(r0, delta.shape[0]):
        move += delta[a] * delta[a]
    scale = 1.0
    if rot > MAX_STEP_RAD * MAX_STEP_RAD:
        scale = MAX_STEP_RAD / np.sqrt(rot)
    if move > max_d * max_d:
        scale = min(scale, max_d / np.sqrt(move))
    if scale < 1.0:
        for a in range(delta.shape[0]):
            delta[a] *= scale


@njit(cache=True, inline='always')
def _rz_matrix(yaw: float) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    out = np.zeros((3, 3))
    out[0, 0], out[0, 1], out[1, 0], out[1, 1], out[2, 2] = c, -s, s, c, 1.0
    return out


@njit(cache=True, inline='always')
def _rodrigues_matrix(wx: float, wy: float, wz: float) -> np.ndarray:
    """Rotation of the rotation vector (wx, wy, wz): I + sin(theta) K + (1 - cos(theta)) K^2."""
    theta = np.sqrt(wx * wx + wy * wy + wz * wz)
    scale = theta if theta > 1e-12 else 1.0
    kx, ky, kz = wx / scale, wy / scale, wz / scale
    skew = np.zeros((3, 3))
    skew[0, 1], skew[0, 2] = -kz, ky
    skew[1, 0], skew[1, 2] = kz, -kx
    skew[2, 0], skew[2, 1] = -ky, kx
    rotation: np.ndarray = np.eye(3) + np.sin(theta) * skew \
        + (1.0 - np.cos(theta)) * (skew @ skew)
    return rotation


@njit(cache=True, nogil=True)
def keep_near_tangent_plane(points: np.ndarray, index: np.ndarray, model: np.ndarray,
                            normals: np.ndarray, limit: float, ok: np.ndarray) -> None:
    """In place: ``ok[i]`` (N,) stays True only where point i lies closer than ``limit`` to
    the tangent plane of its matched model sample ``index[i]`` (|n . (p - m)|, the products
    summed over x, y, z in that order, as numpy's row sums do)."""
    for i in range(points.shape[0]):
        if ok[i]:
            j = index[i]
            d = (normals[j, 0] * (points[i, 0] - model[j, 0])
                 + normals[j, 1] * (points[i, 1] - model[j, 1])
                 + normals[j, 2] * (points[i, 2] - model[j, 2]))
            if abs(d) >= limit:
                ok[i] = False


@njit(cache=True, nogil=True)
def self_visible(points: np.ndarray, normals: np.ndarray, cell_rad: float,
                 depth_tolerance: float) -> np.ndarray:
    """(N,) bool: model points (camera frame) that face the camera at the origin and are not
    hidden by the model itself, by a z-buffer over direction cells of ``cell_rad``
    (floor((x / z) / cell_rad), floor((y / z) / cell_rad)); a point is visible within
    ``depth_tolerance`` metres of its cell's nearest depth."""
    n = points.shape[0]
    visible = np.zeros(n, np.bool_)
    candidate = np.zeros(n, np.bool_)
    u = np.zeros(n, np.int64)
    v = np.zeros(n, np.int64)
    u_min, v_min = np.int64(0), np.int64(0)
    found = False
    for i in range(n):
        x, y, z = points[i, 0], points[i, 1], points[i, 2]
        if normals[i, 0] * x + normals[i, 1] * y + normals[i, 2] * z < 0 and z > 1e-6:
            candidate[i] = True
            u[i] = np.int64(np.floor(x / z / cell_rad))
            v[i] = np.int64(np.floor(y / z / cell_rad))
            if not found or u[i] < u_min:
                u_min = u[i]
            if not found or v[i] < v_min:
                v_min = v[i]
            found = True
    if not found:
        return visible
    u_span, v_span = np.int64(0), np.int64(0)
    for i in range(n):
        if candidate[i]:
            u_span = max(u_span, u[i] - u_min + 1)
            v_span = max(v_span, v[i] - v_min + 1)
    nearest = np.full(u_span * v_span, np.inf)
    for i in range(n):
        if candidate[i]:
            key = (u[i] - u_min) * v_span + (v[i] - v_min)
            nearest[key] = min(nearest[key], points[i, 2])
    for i in range(n):
        if candidate[i]:
            key = (u[i] - u_min) * v_span + (v[i] - v_min)
            visible[i] = points[i, 2] <= nearest[key] + depth_tolerance
    return visible
