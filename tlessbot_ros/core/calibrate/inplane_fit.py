"""The in-plane fit of the scene calibration (steps 3 and 4 of :mod:`.scene`): the side view's
parts moved onto the top view's by a turn about the table normal and a shift along the table.

The coarse fit matches blobs (MSAC over one- and two-pair hypotheses, Torr & Zisserman, CVIU
2000); the fine fit is an in-plane ICP of the part points (Besl & McKay, PAMI 1992)."""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import cast

import numpy as np

from tlessbot_ros.core.calibrate.inplane import (
    inplane_parameters,
    inplane_transform,
    procrustes_2d,
)
from tlessbot_ros.core.calibrate.observation import ViewObservation
from tlessbot_ros.core.calibrate.params import SceneCalibrationParams
from tlessbot_ros.core.common.geometry import transform_points


def median_plane(planes: Sequence[np.ndarray]) -> np.ndarray:
    """(4,) the component-wise median of planes, its normal renormalised."""
    median = np.median(np.asarray(planes, np.float64), axis=0)
    scale = np.linalg.norm(median[:3])
    return cast(np.ndarray, median / scale)


@dataclass
class WorldView:
    """One view of one frame in its levelled world frame: (N, 3) points and, per usable blob,
    (x, y, height) of its upper part."""

    points: np.ndarray
    features: np.ndarray


def world_view(view: ViewObservation, T_world_camera: np.ndarray) -> WorldView:
    points = transform_points(T_world_camera, view.points)
    features = []
    for b in range(view.blobs):
        if view.cut[b]:
            continue
        mine = points[view.blob == b]
        height = float(np.percentile(mine[:, 2], 95))
        upper = mine[mine[:, 2] >= 0.6 * height]
        x, y = upper[:, :2].mean(axis=0)
        features.append((x, y, height))
    return WorldView(points, np.asarray(features, np.float64).reshape(-1, 3))


# --------------------------------------------------------------------------- coarse fit
@dataclass
class CoarseFit:
    G: np.ndarray
    frames_matched: int
    matches: int
    matched: list[int]          # frames with a match


def _padded(arrays: Sequence[np.ndarray]) -> np.ndarray:
    """(F, M, 3) float64, NaN where a frame has fewer than M rows."""
    width = max((len(a) for a in arrays), default=0)
    out = np.full((len(arrays), max(width, 1), 3), np.nan)
    for k, a in enumerate(arrays):
        out[k, :len(a)] = a
    return out


def _match_costs(G_params: np.ndarray, top: np.ndarray, side: np.ndarray,
                 params: SceneCalibrationParams) -> tuple[np.ndarray, np.ndarray]:
    """For H hypotheses (H, 3) (yaw, x, y) and padded features (F, N, 3), (F, M, 3): the
    (H, F, M, N) planar distances (inf where heights disagree or padding) and the mutual
    nearest pairs within ``match_distance_m`` (bool, same shape)."""
    c, s = np.cos(G_params[:, 0]), np.sin(G_params[:, 0])
    sx, sy = side[None, ..., 0], side[None, ..., 1]                     # (1, F, M)
    mx = c[:, None, None] * sx - s[:, None, None] * sy + G_params[:, 1, None, None]
    my = s[:, None, None] * sx + c[:, None, None] * sy + G_params[:, 2, None, None]
    dx = mx[..., None] - top[None, :, None, :, 0]
    dy = my[..., None] - top[None, :, None, :, 1]
    distance = np.hypot(dx, dy)
    heights = np.abs(side[:, :, None, 2] - top[:, None, :, 2]) <= params.match_height_m
    distance = np.where(heights[None] & np.isfinite(distance), distance, np.inf)
    best_n = distance.argmin(axis=3, keepdims=True)
    best_m = distance.argmin(axis=2, keepdims=True)
    shape = distance.shape
    mutual = (np.arange(shape[3])[None, None, None, :] == best_n) & \
        (np.arange(shape[2])[None, None, :, None] == best_m)
    return distance, mutual & (distance < params.match_distance_m)


def _hypotheses(world: list[dict[str, WorldView]], params: SceneCalibrationParams,
                top: str, side: str, rng: np.random.Generator) -> np.ndarray:
    """(H, 3) (yaw, x, y) from one blob pair (shift only) and from two pairs of one frame
    whose spans agree (the turn that lines the spans up, the shift that lines their middles
    up), inside the prior's gate."""
    singles, doubles = [], []
    for views in world:
        T, S = views[top].features, views[side].features
        if len(T) == 0 or len(S) == 0:
            continue
        i, k = np.nonzero(np.abs(T[:, None, 2] - S[None, :, 2]) <= params.match_height_m)
        singles.append(np.column_stack([np.zeros(len(i)), T[i, 0] - S[k, 0],
                                        T[i, 1] - S[k, 1]]))
        if len(T) < 2 or len(S) < 2:
            continue
        i, j = np.triu_indices(len(T), 1)
        k, m = np.nonzero(~np.eye(len(S), dtype=bool))
        a, b = np.repeat(i, len(k)), np.repeat(j, len(k))       # every top pair ...
        c, d = np.tile(k, len(i)), np.tile(m, len(i))           # ... with every side pair
        span_t, span_s = T[b, :2] - T[a, :2], S[d, :2] - S[c, :2]
        agree = np.abs(np.hypot(*span_t.T) - np.hypot(*span_s.T)) <= params.match_distance_m
        a, b, c, d, span_t, span_s = (x[agree] for x in (a, b, c, d, span_t, span_s))
        yaw = np.arctan2(span_t[:, 1], span_t[:, 0]) - np.arctan2(span_s[:, 1], span_s[:, 0])
        yaw = (yaw + np.pi) % (2 * np.pi) - np.pi
        middle_t, middle_s = (T[a, :2] + T[b, :2]) / 2, (S[c, :2] + S[d, :2]) / 2
        cos, sin = np.cos(yaw), np.sin(yaw)
        doubles.append(np.column_stack([
            yaw, middle_t[:, 0] - (cos * middle_s[:, 0] - sin * middle_s[:, 1]),
            middle_t[:, 1] - (sin * middle_s[:, 0] + cos * middle_s[:, 1])]))
    kept = []
    for pieces in (singles, doubles):
        found = np.vstack(pieces) if pieces else np.zeros((0, 3))
        gate = (np.abs(found[:, 0]) <= np.radians(params.prior_max_yaw_deg)) & \
            (np.hypot(found[:, 1], found[:, 2]) <= params.prior_max_shift_m)
        found = found[gate]
        if len(found) > params.hypotheses:
            found = found[rng.choice(len(found), params.hypotheses, replace=False)]
        kept.append(found)
    # the prior itself competes too: a right rig needs no hypothesis to be found
    return np.vstack([np.zeros((1, 3)), *kept])


def coarse_fit(world: list[dict[str, WorldView]], params: SceneCalibrationParams,
                top: str, side: str) -> CoarseFit | None:
    """Best hypothesis by MSAC over every frame, refitted on its matches three times."""
    T = _padded([views[top].features for views in world])
    S = _padded([views[side].features for views in world])
    if not (np.isfinite(T).any() and np.isfinite(S).any()):
        return None
    candidates = _hypotheses(world, params, top, side, np.random.default_rng(params.seed))
    best, best_score = None, -np.inf
    for start in range(0, len(candidates), 64):   # bounded memory: (64, F, M, N)
        chunk = candidates[start:start + 64]
        distance, inlier = _match_costs(chunk, T, S, params)
        cost = np.where(inlier, 1.0 - (distance / params.match_distance_m) ** 2, 0.0)
        score = cost.sum(axis=(1, 2, 3))
        k = int(np.argmax(score))
        if score[k] > best_score:
            best, best_score = chunk[k], float(score[k])
    if best is None or best_score <= 0:
        return None
    G = inplane_transform(*best)
    for _ in range(3):
        distance, inlier = _match_costs(np.array(inplane_parameters(G))[None], T, S, params)
        f, m, n = np.nonzero(inlier[0])
        if len(f) == 0:
            return None
        if len(f) == 1:   # one pair fixes the shift only: keep the turn
            moved = transform_points(G, S[f, m])
            G = inplane_transform(0.0, *(T[f, n, :2] - moved[:, :2])[0]) @ G
        else:
            G = procrustes_2d(S[f, m], T[f, n])
    matched = sorted(set(int(k) for k in f))
    return CoarseFit(G, len(matched), len(f), matched)


# --------------------------------------------------------------------------- fine fit
def _normals(cloud: np.ndarray, at: np.ndarray, k: int = 10) -> np.ndarray:
    """(M, 3) unit normals at the points ``at`` of a (N, 3) cloud: the direction of least
    spread of their ``k`` nearest neighbours."""
    from scipy.spatial import cKDTree

    k = min(k, len(cloud))
    _, index = cKDTree(cloud).query(at, k=k)
    near = cloud[index.reshape(len(at), k)]
    centred = near - near.mean(axis=1, keepdims=True)
    return np.linalg.eigh(np.einsum('mki,mkj->mij', centred, centred))[1][:, :, 0]


def _thinned(points: np.ndarray, count: int, rng: np.random.Generator) -> np.ndarray:
    """At most ``count`` of the (N, 3) points, chosen at random (seeded)."""
    if len(points) <= count:
        return points
    return points[np.sort(rng.choice(len(points), count, replace=False))]


@dataclass
class FineFit:
    G: np.ndarray
    pairs: int
    residual_m: float
    overlap: float
    prior_overlap: float
    yaw_sigma_deg: float
    shift_sigma_m: float


def fine_fit(world: list[dict[str, WorldView]], coarse: CoarseFit,
              params: SceneCalibrationParams, top: str, side: str) -> FineFit:
    """In-plane ICP of the side view's part points onto the top view's, over the frames with
    matched parts."""
    from scipy.spatial import cKDTree

    scale = np.array([1.0, 1.0, params.icp_height_weight])
    frames = [world[k] for k in coarse.matched]
    trees = [cKDTree(views[top].points * scale) for views in frames]
    targets = [views[top].points for views in frames]
    rng = np.random.default_rng(params.seed)
    sources = [_thinned(views[side].points, params.icp_points, rng) for views in frames]
    if params.icp_face_tilt_deg < 90.0:
        # Side points on walls the top camera does not see would be pulled onto the nearest
        # top-face edge, a few mm off: points on faces both cameras see carry the fit.
        flat = np.cos(np.radians(params.icp_face_tilt_deg))
        sources = [s[np.abs(_normals(views[side].points, s)[:, 2]) >= flat]
                   for s, views in zip(sources, frames)]

    def pairs(G: np.ndarray, distance: float) -> list[tuple[np.ndarray, np.ndarray]]:
        """Per frame, (moved side points, their nearest top points) within ``distance``."""
        out = []
        for tree, target, source in zip(trees, targets, sources):
            moved = transform_points(G, source)
            gap, index = tree.query(moved * scale, distance_upper_bound=distance)
            near = np.isfinite(gap)
            out.append((moved[near], target[index[near]]))
        return out

    G = coarse.G
    distance = params.icp_start_distance_m
    for _ in range(params.icp_iterations):
        found = pairs(G, distance)
        source = np.concatenate([s for s, _ in found])
        if len(source) < 3:
            break
        step = procrustes_2d(source, np.concatenate([t for _, t in found]))
        G = step @ G
        yaw, x, y = inplane_parameters(step)
        settled = distance <= params.icp_distance_m
        distance = max(params.icp_distance_m, 0.7 * distance)
        if settled and abs(yaw) < 3e-5 and np.hypot(x, y) < 3e-5:   # 0.002 deg, 0.03 mm
            break
    found = pairs(G, params.icp_distance_m)
    total = sum(len(s) for s in sources)
    source = np.concatenate([s for s, _ in found])
    target = np.concatenate([t for _, t in found])
    residual = float(np.sqrt(np.mean(np.sum((source - target)[:, :2] ** 2, axis=1)))) \
        if len(source) else float('nan')
    prior = sum(len(s) for s, _ in pairs(np.eye(4), params.icp_distance_m))
    # per-frame fits from the common solution: their spread says how well it is determined
    steps = np.array([inplane_parameters(procrustes_2d(s, t)) for s, t in found if len(s) >= 10])
    if len(steps) >= 2:
        spread = steps.std(axis=0, ddof=1) / np.sqrt(len(steps))
        yaw_sigma, shift_sigma = float(np.degrees(spread[0])), float(np.hypot(*spread[1:]))
    else:
        yaw_sigma = shift_sigma = float('inf')
    return FineFit(G, len(source), residual, len(source) / max(total, 1), prior / max(total, 1),
                 yaw_sigma, shift_sigma)


__all__ = ['CoarseFit', 'FineFit', 'WorldView', 'coarse_fit', 'fine_fit', 'median_plane',
           'world_view']
