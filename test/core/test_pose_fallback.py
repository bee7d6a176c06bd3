"""core.pose.fallback: the bounded 'views' fallback finds rendered T-LESS parts in poses the
table path cannot describe; forced mode; symmetric parts; its work is a fixed amount."""
from __future__ import annotations

import numpy as np
import pytest

from tlessbot_ros.core.common import (
    MeshRenderer,
    default_rig,
    depth_to_points,
    make_transform,
    rotation_about_axis,
)
from tlessbot_ros.core.metrics import pose_error
from tlessbot_ros.core.pose import (
    PoseEstimator,
    PoseParams,
    Refiner,
    TemplateDatabase,
    fallback_candidates,
    fibonacci_sphere,
    near_symmetries,
    rotation_between,
    view_grid,
)
from tlessbot_ros.data import DEFAULT_MODELS_INFO, DEFAULT_TEMPLATES

SIDE = default_rig()['side']
IDS = (4, 5, 21)   # continuous axis, 2-fold, none (BOP models_info)


@pytest.fixture(scope='module')
def parts(tless_models_dir):
    from tlessbot_ros.io.models import load_models
    from tlessbot_ros.tools.support.models_info import load_symmetries
    return (TemplateDatabase.load(DEFAULT_TEMPLATES), load_models(tless_models_dir, ids=IDS),
            load_symmetries(DEFAULT_MODELS_INFO))


def _view(model, T_world_object, *, noise_m=0.0005, seed=0):
    """ROI points (N, 3) of the part rendered alone by the side camera, with depth noise."""
    renderer = MeshRenderer()
    renderer.add_mesh(model.vertices, model.faces, T_world_object)
    view = renderer.render(SIDE.intrinsics, SIDE.T_world_camera)
    points, _ = depth_to_points(view.depth_m, SIDE.intrinsics.K, mask=view.instance == 0)
    return points + np.random.default_rng(seed).normal(0.0, noise_m, points.shape)


def _box_view(model, T_world_object, *, noise_m=0.0005, seed=0):
    """ROI points (N, 3) of the part's image box: the part, and the table (world z = 0) seen
    around it, as a box ROI without a table frame holds them."""
    renderer = MeshRenderer()
    renderer.add_mesh(model.vertices, model.faces, T_world_object)
    view = renderer.render(SIDE.intrinsics, SIDE.T_world_camera)
    part = view.instance == 0
    rows, cols = np.nonzero(part)
    v, u = np.mgrid[rows.min():rows.max() + 1, cols.min():cols.max() + 1]
    table = ~part[v, u]
    rays = np.stack([u[table], v[table], np.ones(table.sum())], axis=1) @ \
        np.linalg.inv(SIDE.intrinsics.K).T                       # camera frame, z = 1
    R, c = SIDE.T_world_camera[:3, :3], SIDE.T_world_camera[:3, 3]
    depth = -c[2] / (rays @ R.T)[:, 2]                             # where world z = 0
    points = np.concatenate([depth_to_points(view.depth_m, SIDE.intrinsics.K, mask=part)[0],
                             rays * depth[:, None]])
    return points + np.random.default_rng(seed).normal(0.0, noise_m, points.shape)


def _leaning(db, obj_id, *, tilt_deg, azimuth_deg, yaw_deg, x=0.0, y=0.0):
    """The part's most probable resting pose, turned by ``yaw_deg``, tilted by ``tilt_deg``
    about a horizontal axis and put back on the table (as if leaning on a neighbour)."""
    obj = db[obj_id]
    T = make_transform(rotation_about_axis([0, 0, 1], np.radians(yaw_deg)), [x, y, 0.0]) @ \
        obj.stable_poses[0]
    a = np.radians(azimuth_deg)
    T = make_transform(rotation_about_axis([np.cos(a), np.sin(a), 0.0], np.radians(tilt_deg)),
                       [0.0, 0.0, 0.0]) @ T
    T[2, 3] -= (obj.model_points @ T[:3, :3].T + T[:3, 3])[:, 2].min()
    return T


def _error(parts, obj_id, T_est, T_world_object):
    _, _, symmetries = parts
    error = pose_error(T_est, SIDE.T_camera_world @ T_world_object, symmetries[obj_id])
    return error.translation_m, error.rotation_deg


@pytest.mark.parametrize('obj_id, tilt, azimuth, yaw', [(21, 25.0, 30.0, 70.0),
                                                       (5, 30.0, 200.0, 10.0),
                                                       (4, 35.0, 120.0, 0.0)])
def test_a_leaning_part_is_found_by_the_forced_fallback(parts, obj_id, tilt, azimuth, yaw):
    db, models, _ = parts
    T_wo = _leaning(db, obj_id, tilt_deg=tilt, azimuth_deg=azimuth, yaw_deg=yaw, x=0.02)
    result = PoseEstimator(db, params=PoseParams(force_fallback=True)).estimate(
        _view(models[obj_id], T_wo), obj_id, T_world_camera=SIDE.T_world_camera)
    t_err, r_err = _error(parts, obj_id, result.best.T_camera_object, T_wo)
    assert t_err < 0.01 and r_err < 5.0     # symmetry-aware: obj_04 turns freely, obj_05 flips
    assert result.best.method == 'views' and result.best.fitness > 0.9
    assert 'table' not in result.timings_ms and 'fallback' in result.timings_ms


def test_where_the_former_fallback_finds_the_pose_the_new_one_does_too(parts):
    # A resting part near a template view: FPFH + RANSAC against every template finds it.
    db, models, _ = parts
    T_wo = make_transform(rotation_about_axis([0, 0, 1], np.radians(30.0)), [0.0, 0.0, 0.0]) @ \
        db[21].stable_poses[0]
    points = _view(models[21], T_wo)
    for method in ('templates', 'views'):
        estimator = PoseEstimator(db, params=PoseParams(fallback_method=method))
        result = estimator.estimate(points, 21)     # no table frame: straight to the fallback
        t_err, r_err = _error(parts, 21, result.best.T_camera_object, T_wo)
        assert t_err < 0.01 and r_err < 5.0, method


def test_forced_mode_never_runs_the_table_path(parts, monkeypatch):
    db, models, _ = parts
    estimator = PoseEstimator(db, params=PoseParams(force_fallback=True))
    monkeypatch.setattr(estimator, '_table_path',
                        lambda *a, **k: pytest.fail('the table path ran'))
    T_wo = make_transform(rotation_about_axis([0, 0, 1], np.radians(50.0)), [0.0, 0.0, 0.0]) @ \
        db[21].stable_poses[0]
    result = estimator.estimate(_view(models[21], T_wo), 21, T_world_camera=SIDE.T_world_camera)
    assert result.best.method == 'views'
    t_err, r_err = _error(parts, 21, result.best.T_camera_object, T_wo)
    assert t_err < 0.01 and r_err < 5.0


def test_a_poor_table_fit_goes_to_the_views_fallback(parts):
    # Leaning 35°: no stable pose explains the view, the table path's fit stays poor.
    db, models, _ = parts
    T_wo = _leaning(db, 21, tilt_deg=35.0, azimuth_deg=100.0, yaw_deg=20.0)
    points = _view(models[21], T_wo)
    result = PoseEstimator(db, params=PoseParams(fallback_fitness=1.01)).estimate(
        points, 21, T_world_camera=SIDE.T_world_camera)
    assert 'table' in result.timings_ms and 'fallback' in result.timings_ms
    t_err, r_err = _error(parts, 21, result.best.T_camera_object, T_wo)
    assert t_err < 0.01 and r_err < 5.0
    table_only = PoseEstimator(db, params=PoseParams(fallback=False)).estimate(
        points, 21, T_world_camera=SIDE.T_world_camera)
    assert result.best.fitness > table_only.best.fitness


@pytest.mark.parametrize('obj_id, yaw', [(21, 140.0), (5, 60.0)])
def test_the_table_in_a_box_roi_is_dropped(parts, obj_id, yaw):
    # One view, no table frame, a box ROI: the table around the part is no face of it.
    db, models, _ = parts
    T_wo = make_transform(rotation_about_axis([0, 0, 1], np.radians(yaw)), [0.0, 0.0, 0.0]) \
        @ db[obj_id].stable_poses[0]
    points = _box_view(models[obj_id], T_wo)
    assert len(points) > 1.5 * len(_view(models[obj_id], T_wo))      # mostly table
    result = PoseEstimator(db).estimate(points, obj_id)
    t_err, r_err = _error(parts, obj_id, result.best.T_camera_object, T_wo)
    assert t_err < 0.01 and r_err < 5.0
    # With the table kept, its points drag the views' centroids (obj_05 ends 113° off).
    kept = PoseEstimator(db, params=PoseParams(fallback_drop_planes=0)).estimate(points, obj_id)
    assert _error(parts, obj_id, kept.best.T_camera_object, T_wo)[1] >= r_err


def test_the_pose_moves_with_the_part(parts):
    db, models, _ = parts
    estimator = PoseEstimator(db, params=PoseParams(force_fallback=True))
    T_a = _leaning(db, 21, tilt_deg=20.0, azimuth_deg=0.0, yaw_deg=0.0)
    move = make_transform(rotation_about_axis([0, 0, 1], np.radians(120.0)), [0.04, -0.03, 0.0])
    est_a = estimator.estimate(_view(models[21], T_a), 21)
    est_b = estimator.estimate(_view(models[21], move @ T_a, seed=1), 21)
    world_a = SIDE.T_world_camera @ est_a.best.T_camera_object
    world_b = SIDE.T_world_camera @ est_b.best.T_camera_object
    error = pose_error(world_b, move @ world_a)
    assert error.translation_m < 0.005 and error.rotation_deg < 3.0


def test_near_and_exact_symmetries(parts):
    db, _, _ = parts
    continuous, two_fold, none = (near_symmetries(db[i]) for i in IDS)
    # obj_04 turns about its z axis (45° steps are exact); obj_05 only by a half-turn about z;
    # obj_21 has none. Exact turns are never tried as near-symmetries.
    assert len(continuous.exact) >= 8 and len(two_fold.exact) == 2 and len(none.exact) == 1
    z_turn = two_fold.exact[1][:3, :3]
    assert np.degrees(np.arccos(np.clip(z_turn[2, 2], -1, 1))) < 5.0     # about z
    for sym in (continuous, two_fold, none):
        np.testing.assert_allclose(sym.exact[0], np.eye(4))
        for S in sym.turns:
            assert all(np.abs(S - E).max() > 1e-6 for E in sym.exact)
    assert len(none.turns) >= 3       # the half-turns about the object axes, at least
    # Views equal up to an exact symmetry are kept once: a part with a continuous axis has far
    # fewer views to score.
    p = PoseParams()
    counts = [len(view_grid(db[i], directions=p.fallback_directions,
                            in_plane_steps=p.fallback_in_plane_steps).rotations) for i in IDS]
    assert counts[2] == p.fallback_directions * p.fallback_in_plane_steps
    assert counts[0] < 0.6 * counts[2] and counts[1] < counts[2]


def test_the_work_is_a_fixed_amount(parts, monkeypatch):
    """ICP runs on a fixed number of poses whatever the part; a spent budget skips the turns."""
    db, models, _ = parts
    p = PoseParams()
    refiner = Refiner(p)
    poses = []
    original = refiner.icp_batch

    def spy(scene_c, obj, T, **kwargs):
        poses.append(len(T))
        return original(scene_c, obj, T, **kwargs)
    monkeypatch.setattr(refiner, 'icp_batch', spy)
    T_wo = _leaning(db, 5, tilt_deg=30.0, azimuth_deg=40.0, yaw_deg=0.0)
    scene = _view(models[5], T_wo)[::3]
    turns = len(near_symmetries(db[5]).turns)
    fallback_candidates(scene, db[5], {}, params=p, refiner=refiner)
    coarse, fine, turned, final = poses
    assert coarse == p.fallback_icp_starts and fine <= p.fallback_refine
    assert turned == min(p.fallback_turned, fine) * turns and final <= p.final_candidates
    poses.clear()
    out = fallback_candidates(scene, db[5], {}, params=p, refiner=refiner, deadline=0.0)
    assert len(poses) == 3 and out        # no turns, still an answer


def test_geometry_helpers():
    directions = fibonacci_sphere(300)
    np.testing.assert_allclose(np.linalg.norm(directions, axis=1), 1.0)
    # evenly spread: every direction has a neighbour within ~12°, none closer than ~6°
    cos = directions @ directions.T - 2.0 * np.eye(300)
    nearest = np.degrees(np.arccos(np.clip(cos.max(axis=1), -1, 1)))
    assert 6.0 < nearest.min() and nearest.max() < 14.0
    for a in ([0, 0, 1.0], [0, 0, -1.0], [1.0, 2.0, -0.5]):
        b = np.array([0.3, -0.2, 1.0])
        R = rotation_between(np.array(a), b)
        np.testing.assert_allclose(R @ (np.array(a) / np.linalg.norm(a)), b / np.linalg.norm(b),
                                   atol=1e-12)
        np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
    many = rotation_between(directions, [0.0, 0.0, -1.0])
    np.testing.assert_allclose(many @ directions[:, :, None], np.broadcast_to(
        [[0.0], [0.0], [-1.0]], (300, 3, 1)), atol=1e-12)


def test_bad_fallback_settings_are_refused():
    with pytest.raises(ValueError, match='fallback_method'):
        PoseParams(fallback_method='ppf')
    with pytest.raises(ValueError, match='fallback_directions'):
        PoseParams(fallback_directions=0)
    with pytest.raises(ValueError, match='fallback_voxel_scale'):
        PoseParams(fallback_voxel_scale=0.0)
