"""Class verification by the pose fit (PerceptionPipeline.estimate_poses with candidates)."""
from __future__ import annotations

import re

import numpy as np
import pytest

from tlessbot_ros.core.common import default_rig, transform_points
from tlessbot_ros.core.pipeline import (
    ClassifyParams,
    FitParams,
    LocaliseParams,
    PerceptionPipeline,
    ViewInput,
)
from tlessbot_ros.core.pose import PoseParams

SIDE = default_rig()['side']


@pytest.fixture(scope='module')
def scene(part21_seen_from_the_side):
    db, depth, mask, T_camera_object = part21_seen_from_the_side
    depth = depth + np.random.default_rng(0).normal(0, 0.0005, depth.shape).astype(
        np.float32) * (depth > 0)
    inputs = {'side': ViewInput(rgb=None, depth_m=depth, intrinsics=SIDE.intrinsics,
                                T_world_camera=SIDE.T_world_camera)}
    return db, inputs, {'side': mask.astype(np.uint16)}, T_camera_object


def _counting(pipeline):
    calls = []
    estimate = pipeline.pose_estimator.estimate

    def counted(points, obj_id, **kwargs):
        calls.append(obj_id)
        return estimate(points, obj_id, **kwargs)
    pipeline.pose_estimator.estimate = counted
    return calls


def test_a_wrong_first_class_is_overruled_by_the_better_fit(scene):
    db, inputs, labels, T_gt = scene
    pipeline = PerceptionPipeline(templates=db)
    calls = _counting(pipeline)
    [detection] = pipeline.estimate_poses(inputs, labels, {1: (5, 21)})
    assert calls == [5, 21]
    assert detection.obj_id == 21 and detection.class_rank == 1
    assert np.linalg.norm(detection.pose.T_camera_object[:3, 3] - T_gt[:3, 3]) < 0.01


def test_each_detection_is_handed_over_as_soon_as_it_is_complete(scene):
    db, inputs, labels, _ = scene
    two = labels['side'].copy()
    rows = np.flatnonzero(two.any(axis=1))
    two[rows[len(rows) // 2]:] *= 2              # the part's lower half is a second instance
    # halves of one part are fragments of each other: without the fragment check both go out
    pipeline = PerceptionPipeline(templates=db, fit_params=FitParams(fragment_overlap=0.0))
    calls = _counting(pipeline)
    handed = []
    detections = pipeline.estimate_poses(
        inputs, {'side': two}, {1: (21,), 2: (21,)},
        on_detection=lambda d: handed.append((d.instance_id, len(calls))))
    assert [d.instance_id for d in detections] == [1, 2]
    assert handed == [(1, 1), (2, 2)]            # instance 1 went out before 2 was fitted


def test_two_halves_of_one_part_give_one_pose(scene):
    db, inputs, labels, T_gt = scene
    two = labels['side'].copy()
    rows = np.flatnonzero(two.any(axis=1))
    two[rows[len(rows) // 2]:] *= 2
    handed = []
    detections = PerceptionPipeline(templates=db).estimate_poses(
        inputs, {'side': two}, {1: (21,), 2: (21,)}, on_detection=handed.append)
    assert len(detections) == 1 and handed == detections
    assert np.linalg.norm(detections[0].pose.T_camera_object[:3, 3] - T_gt[:3, 3]) < 0.03


def test_the_class_is_chosen_on_unpolished_fits_and_only_the_winner_is_polished(scene):
    # A wrong class converges under the polish too, so the candidates are compared on their
    # short fits and only the winner's finalists are polished (PoseParams.polish_iterations).
    db, inputs, labels, T_gt = scene
    pipeline = PerceptionPipeline(templates=db)
    assert pipeline.pose_estimator.params.polish_iterations > 0
    estimate, polish = pipeline.pose_estimator.estimate, pipeline.pose_estimator.polish
    estimated, polished = [], []

    def spy_estimate(points, obj_id, **kwargs):
        estimated.append((obj_id, kwargs.get('polish')))
        return estimate(points, obj_id, **kwargs)

    def spy_polish(points, result, **kwargs):
        polished.append(result.obj_id)
        out = polish(points, result, **kwargs)
        assert out.polished and out.best is not None
        return out
    pipeline.pose_estimator.estimate = spy_estimate
    pipeline.pose_estimator.polish = spy_polish
    [detection] = pipeline.estimate_poses(inputs, labels, {1: (5, 21)})
    assert estimated == [(5, False), (21, False)] and polished == [21]
    assert np.linalg.norm(detection.pose.T_camera_object[:3, 3] - T_gt[:3, 3]) < 0.01
    # ... and the class decision is the one of the unpolished pipeline
    unpolished = PerceptionPipeline(templates=db, pose=PoseParams(polish_iterations=0))
    [plain] = unpolished.estimate_poses(inputs, labels, {1: (5, 21)})
    assert (detection.obj_id, detection.class_rank) == (plain.obj_id, plain.class_rank) \
        == (21, 1)


def test_a_good_first_fit_is_accepted_without_trying_the_others(scene):
    db, inputs, labels, _ = scene
    pipeline = PerceptionPipeline(templates=db)
    calls = _counting(pipeline)
    [detection] = pipeline.estimate_poses(inputs, labels, {1: (21, 5)})
    assert calls == [21] and detection.pose.fitness >= FitParams().verify_accept_fitness
    assert detection.obj_id == 21 and detection.class_rank == 0


def test_one_candidate_is_the_classifier_alone(scene):
    db, inputs, labels, _ = scene
    pipeline = PerceptionPipeline(templates=db)
    [detection] = pipeline.estimate_poses(inputs, labels, {1: 5})
    assert detection.obj_id == 5 and detection.class_rank == 0
    assert pipeline.estimate_poses(inputs, labels, {1: (0, 99)}) == []   # unknown, no templates


def test_a_region_no_candidate_fits_gets_no_ransac_fallback(scene):
    db, inputs, labels, _ = scene
    depth = inputs['side'].depth_m.copy()
    junk = np.zeros_like(labels['side'])
    junk[40:80, 40:80] = 1
    depth[junk > 0] = 0.40      # a flat card floating 40 cm from the camera: no part
    views = {'side': ViewInput(rgb=None, depth_m=depth, intrinsics=SIDE.intrinsics,
                               T_world_camera=SIDE.T_world_camera)}
    pipeline = PerceptionPipeline(templates=db, fit_params=FitParams(unknown_below_fitness=0,
                                                                 unknown_below_cover=0))
    calls = _counting(pipeline)
    [detection] = pipeline.estimate_poses(views, {'side': junk}, {1: (5, 21)})
    assert calls == [5, 21]      # both verified, no third (fallback) call
    assert detection.pose.fitness < FitParams().fallback_min_fitness
    # with the unknown rule on, such a region is reported unknown (#40 item 5)
    rule_on = PerceptionPipeline(templates=db, fit_params=FitParams(unknown_below_fitness=0.7))
    [detection] = rule_on.estimate_poses(views, {'side': junk}, {1: (5, 21)})
    assert detection.obj_id == 0 and detection.pose is None


def test_both_views_segmented_at_once_give_the_labels_of_one_after_the_other(tless_models_dir):
    from tlessbot_ros.io.models import load_models
    from tlessbot_ros.sim.simulator import SimParams, Simulator

    rig = default_rig()
    sim = Simulator(load_models(tless_models_dir, ids=[5, 21]), rig=rig,
                    params=SimParams(parts_min=2, parts_max=2), seed=11)
    frame = sim.frame(0)
    views = {name: ViewInput(view.rgb, view.depth_mm.astype(np.float32) / 1000.0,
                             view.intrinsics, view.T_world_camera)
             for name, view in frame.views.items()}
    labels = {parallel: PerceptionPipeline(rig=rig, localise_params=LocaliseParams(
        parallel_views=parallel)).localise(views).labels for parallel in (False, True)}
    assert labels[True]['side'].max() >= 2
    for camera in ('top', 'side'):
        np.testing.assert_array_equal(labels[True][camera], labels[False][camera])


def test_a_bad_top_view_fails_the_frame_with_its_own_error():
    from tlessbot_ros.core.localise import FusionParams

    blank = ViewInput(np.zeros((48, 64, 3), np.uint8), None, SIDE.intrinsics)
    bad_top = ViewInput(np.zeros((4, 4), np.uint8), None, SIDE.intrinsics)   # not (H, W, 3)
    pipeline = PerceptionPipeline(fusion=FusionParams(method='side_only'))
    with pytest.raises(ValueError, match=r'got shape \(4, 4\)'):   # raised in the helper
        pipeline.localise({'top': bad_top, 'side': blank})
    # the helper thread still segments the next frame's top view
    labels = pipeline.localise({'top': blank, 'side': blank}).labels
    assert labels['side'].shape == (48, 64) and not labels['side'].any()


@pytest.fixture(scope='module')
def lookalikes(tless_models_dir):
    """Database of the look-alikes obj_21 and obj_22 (side camera, 4 views) and obj_21 lying
    on the table, seen by the side camera with 0.5 mm depth noise."""
    from tlessbot_ros.core import pose as tpl
    from tlessbot_ros.core.common import MeshRenderer, make_transform, rotation_about_axis
    from tlessbot_ros.io.models import load_models, stable_poses

    models = load_models(tless_models_dir, ids=[21, 22])
    db = tpl.build_database(
        [(i, m.vertices, m.faces, [(p.T_table_object, p.probability) for p in stable_poses(m)],
          m.diameter_m) for i, m in models.items()],
        intrinsics=SIDE.intrinsics, T_world_camera=SIDE.T_world_camera,
        params=tpl.TemplateParams(n_views=4))
    T_world_object = make_transform(rotation_about_axis([0, 0, 1], np.radians(40)),
                                    [0.01, 0.02, 0]) @ db[21].stable_poses[0]
    renderer = MeshRenderer()
    renderer.add_mesh(models[21].vertices, models[21].faces, T_world_object)
    view = renderer.render(SIDE.intrinsics, SIDE.T_world_camera)
    mask = view.instance == 0
    depth = np.where(mask, view.depth_m + np.random.default_rng(1).normal(
        0, 0.0005, mask.shape), 0).astype(np.float32)
    inputs = {'side': ViewInput(rgb=None, depth_m=depth, intrinsics=SIDE.intrinsics,
                                T_world_camera=SIDE.T_world_camera)}
    return db, inputs, {'side': mask.astype(np.uint16)}, models


def test_a_lookalike_is_named_by_the_depth_it_explains(lookalikes):
    from tlessbot_ros.core.common import raycasting_scene
    from tlessbot_ros.core.pose import visible_difference

    db, inputs, labels, models = lookalikes
    assert db[21].lookalikes == (22,) and db[22].lookalikes == (21,)
    [detection] = PerceptionPipeline(templates=db).estimate_poses(inputs, labels, {1: (22,)})
    assert detection.obj_id == 21 and detection.class_rank == 1   # overruled, not a candidate
    # this view does show the difference, at the pose the fit found
    shows = visible_difference(raycasting_scene(models[21].vertices, models[21].faces),
                               raycasting_scene(models[22].vertices, models[22].faces),
                               detection.pose.T_camera_object, SIDE.intrinsics,
                               labels['side'] > 0)
    assert shows > 0.02
    [kept] = PerceptionPipeline(templates=db).estimate_poses(inputs, labels, {1: (21,)})
    assert kept.obj_id == 21 and kept.class_rank == 0
    without = PerceptionPipeline(templates=db, fit_params=FitParams(lookalike_check=False))
    assert without.estimate_poses(inputs, labels, {1: (22,)})[0].obj_id == 22


def test_the_lookalike_check_reads_the_part_in_the_other_view_too(lookalikes):
    from tlessbot_ros.core.common import MeshRenderer

    db, inputs, labels, models = lookalikes
    top = default_rig()['top']
    [detection] = PerceptionPipeline(templates=db).estimate_poses(inputs, labels, {1: (22,)})
    T_world_object = SIDE.T_world_camera @ detection.pose.T_camera_object
    renderer = MeshRenderer()
    renderer.add_mesh(models[21].vertices, models[21].faces, T_world_object)
    view = renderer.render(top.intrinsics, top.T_world_camera)
    mask = view.instance == 0
    both = {**inputs, 'top': ViewInput(rgb=None, depth_m=np.where(mask, view.depth_m, 0).astype(
        np.float32), intrinsics=top.intrinsics, T_world_camera=top.T_world_camera)}
    both_labels = {**labels, 'top': mask.astype(np.uint16)}
    seen = []
    for all_views in (True, False):
        pipeline = PerceptionPipeline(templates=db,
                                      fit_params=FitParams(lookalike_all_views=all_views))
        resolve = pipeline.lookalike.resolve

        def spy(obj_id, T, points, *, more_views=(), resolve=resolve, **options):
            seen.append(more_views)
            return resolve(obj_id, T, points, more_views=more_views, **options)

        pipeline.lookalike.resolve = spy
        [found] = pipeline.estimate_poses(both, both_labels, {1: (22,)})
        assert found.obj_id == 21 and found.view == 'side'
    [(points, T_top_side)], none = seen
    assert none == () and len(points) == mask.sum()
    np.testing.assert_allclose(T_top_side, np.linalg.inv(top.T_world_camera) @ SIDE.T_world_camera)
    # the top view's points lie on the part where the side view's pose, carried over, puts it
    in_top = transform_points(T_top_side @ detection.pose.T_camera_object,
                              models[21].vertices.astype(np.float64))
    assert np.linalg.norm(points.mean(axis=0) - in_top.mean(axis=0)) < 0.02


def test_replace_changes_settings_and_shares_the_templates(lookalikes):
    from tlessbot_ros.core.pose import PoseParams

    db, inputs, labels, _ = lookalikes
    pipeline = PerceptionPipeline(templates=db)
    without = pipeline.replace(fit_params=FitParams(lookalike_check=False))
    assert without.estimate_poses(inputs, labels, {1: (22,)})[0].obj_id == 22
    assert pipeline.estimate_poses(inputs, labels, {1: (22,)})[0].obj_id == 21   # unchanged
    assert without.pose_estimator is pipeline.pose_estimator and without.lookalike is None
    other_pose = pipeline.replace(pose=PoseParams(icp_iterations=2))
    assert other_pose.pose_estimator.params.icp_iterations == 2
    assert other_pose.pose_estimator.database is db and other_pose.lookalike is \
        pipeline.lookalike
    with pytest.raises(TypeError, match='templates'):
        pipeline.replace(templates=db)


def test_a_sure_classifier_alone_names_a_part_seen_only_from_the_top():
    from tlessbot_ros.core.recognise import UNKNOWN_ID, HogParams, LinearClassifier

    def pipeline(scale, **params):
        model = LinearClassifier(np.zeros((HogParams().feature_dim, 3), np.float32),
                                 np.zeros(3, np.float32), np.array([4, 7, 9]), margin_scale=scale)
        return PerceptionPipeline(classifier=model, classify_params=ClassifyParams(**params))

    sure = pipeline(10.0)   # top_view_verify_below_margin 0.25: unsure below a margin of 2.5
    assert sure.verification_candidates(7, 2.0, [7, 4, 9], 'top') == (7, 4, 9)
    assert sure.verification_candidates(7, 3.0, [7, 4, 9], 'top') == (7,)
    assert sure.verification_candidates(7, 3.0, [7, 4, 9], 'side') == (7, 4, 9)
    assert sure.verification_candidates(UNKNOWN_ID, 0.0, [7, 4, 9], 'top') == ()
    assert pipeline(10.0, top_view_verify_below_margin=np.inf).verification_candidates(
        7, 1e9, [7, 4], 'top') == (7, 4)
    assert pipeline(0.0).verification_candidates(7, 1e9, [7, 4], 'top') == (7, 4)  # no scale


@pytest.mark.parametrize('params_class, field, value, fix', [
    (ClassifyParams, 'class_candidates', 5, '1..4'),
    (ClassifyParams, 'min_instance_px', 0, 'at least 1'),
    (ClassifyParams, 'top_view_verify_below_margin', -1.0, 'inf: always verify'),
    (FitParams, 'lookalike_tolerance_m', 0.0, '> 0 m'),
    (FitParams, 'lookalike_min_z', -1.0, '0: any surplus'),
    (FitParams, 'fragment_overlap', 1.5, '[0, 1)'),
    (FitParams, 'fallback_min_fitness', 1.5, '0..1'),
    (FitParams, 'min_roi_points', 2, 'at least 3'),
])
def test_stage_params_reject_values_and_say_how_to_fix_them(params_class, field, value, fix):
    with pytest.raises(ValueError, match=f'{field} must .*{re.escape(fix)}.*got {value}'):
        params_class(**{field: value})


def test_the_stage_params_are_the_fields_of_the_former_pipeline_params():
    from dataclasses import fields

    names = [f.name for cls in (LocaliseParams, ClassifyParams, FitParams) for f in fields(cls)]
    assert sorted(names) == sorted([
        'min_instance_px', 'min_roi_points', 'table_clearance_m', 'reject_margin',
        'class_candidates', 'top_view_verify_below_margin', 'verify_accept_fitness',
        'verify_rmse_weight', 'fallback_min_fitness', 'lookalike_check',
        'lookalike_tolerance_m', 'parallel_views',
        'lookalike_min_z', 'lookalike_all_views',   # session 13: the twins
        'fragment_overlap',   # added after the split (one part, one pose)
        'table_plane', 'table_plane_max_angle_deg', 'table_plane_max_offset_m',   # #23
        'fit_rank_below_margin', 'fit_rank_max_candidates', 'fit_rank_min_fitness',
        'fit_rank_coverage_weight',   # #40: recognition by fit
        'unknown_below_fitness', 'unknown_without_fit',   # #40 item 5: unknown stays unknown
        'unknown_in_outline', 'unknown_below_cover',   # #40 item 5: the fitted outline
        'flat',   # #41: flat parts: the face that is up (depth and colour image)
        'verify_inlier_m', 'verify_overrule_margin', 'verify_points',   # #40: real depth
        'steep_angle_deg',
        'split_unexplained',   # #41: two touching parts found as one, divided after the fit
        'join_refit_cover', 'join_refit_gap_px',   # #41: one part in two pieces, fitted once
        'join_refit_touching',   # #41: touching pieces whatever their centroids, unknown ones
        'trim_to_fit_px',   # #41: a fitted part's region trimmed to its fitted outline
        'rim_colour_below',   # #41: a region's ring of blended colour peeled off
        'edge_band_px',   # #41: a band along a fitted part's edge is no part
        'same_part_share',   # #41: two fits of one class in the same space are one part
        'split_thick_parts',   # #41: piles: the division after the fit for thick parts too
        'split_refit_below',   # #41: piles: a badly explained region refitted on its halves
        'turns',   # #41: near-symmetric turns told apart by the colour image
        'resting',   # #41: a fit on the table levelled onto a stable pose of its part
        'table_clearance_noise',   # #41: box mode, the clearance from the table's noise
        'box_cover',   # #41: box mode, each pose weighed by the share of its box it covers
        'lookalike_edge_min_z',   # #41: look-alikes told apart on the image's edges
        'lookalike_shut_holes',   # #41: a twin's hole that the image shows shut votes against it
        'lookalike_refine'])   # #41: twins open at the fit each refined on per-pixel depth


# ------------------------------------------------------------------ the table plane seen in depth
@pytest.fixture(scope='module')
def part_on_the_table(part21_seen_from_the_side):
    """The side view of object 21 on the table, the table in the depth too (D415-like noise):
    (database, depth, labels, T_camera_object)."""
    from tlessbot_ros.core.common import table_with_box

    db, part_depth, mask, T_camera_object = part21_seen_from_the_side
    _, table_depth, _ = table_with_box(SIDE.intrinsics, SIDE.T_world_camera,
                                       box_size_m=(1e-6, 1e-6, 1e-6))
    depth = np.where(mask, part_depth, table_depth)
    depth = depth + np.random.default_rng(0).normal(0, 1.0, depth.shape) * 0.0021 * depth ** 2
    return db, depth.astype(np.float32), {'side': mask.astype(np.uint16)}, T_camera_object


class _Recorder:
    """A PartFitter that fits nothing and keeps the jobs."""

    def __init__(self):
        self.jobs = []

    def fit_all(self, jobs, fit_here, on_done):
        self.jobs += jobs


def _pose_error(T, T_gt):
    cos = (np.trace(T[:3, :3].T @ T_gt[:3, :3]) - 1.0) / 2.0
    return np.linalg.norm(T[:3, 3] - T_gt[:3, 3]), np.degrees(np.arccos(np.clip(cos, -1, 1)))


def test_one_view_without_extrinsics_takes_the_table_path(part_on_the_table, monkeypatch):
    from tlessbot_ros.core.pose import estimator

    db, depth, labels, T_gt = part_on_the_table
    monkeypatch.setattr(estimator, 'ransac_candidates', lambda *a, **k: pytest.fail('RANSAC'))
    views = {'side': ViewInput(rgb=None, depth_m=depth, intrinsics=SIDE.intrinsics)}
    pipeline = PerceptionPipeline(templates=db)
    [detection] = pipeline.estimate_poses(views, labels, {1: 21}, box_mode=True)
    assert detection.pose.method == 'table'
    error_m, error_deg = _pose_error(detection.pose.T_camera_object, T_gt)
    assert error_m < 0.005 and error_deg < 5.0
    table = pipeline.table_frames['side']
    assert table.source == 'observed' and table.rig_angle_deg is None
    # the frame's heights are the rig's, whatever its yaw and origin
    points = np.random.default_rng(0).uniform(-0.1, 0.1, (10, 3)) + [0, 0, 0.6]
    np.testing.assert_allclose(transform_points(table.T_world_camera, points)[:, 2],
                               transform_points(SIDE.T_world_camera, points)[:, 2], atol=5e-4)


def test_the_table_frame_in_each_mode(part_on_the_table):
    from tlessbot_ros.core.common import make_transform, rotation_about_axis

    db, depth, labels, _ = part_on_the_table
    tilted = make_transform(rotation_about_axis([1.0, 0, 0], np.radians(3)), [0, 0, 0.01]) \
        @ SIDE.T_world_camera          # a rig measured 3° and 1 cm off

    def job_frame(mode, T_world_camera):
        recorder = _Recorder()
        pipeline = PerceptionPipeline(templates=db, fit_params=FitParams(table_plane=mode))
        views = {'side': ViewInput(None, depth, SIDE.intrinsics, T_world_camera)}
        pipeline.estimate_poses(views, labels, {1: 21}, fitter=recorder)
        [job] = recorder.jobs
        return job.T_world_camera, pipeline.table_frames['side']

    # 'rig' without extrinsics: no table frame (every part to RANSAC), no plane looked for
    T, table = job_frame('rig', None)
    assert T is None and table.source == 'none' and table.observed is None
    # 'auto' keeps a rig that agrees with the depth as it is (same results as before)
    T, table = job_frame('auto', SIDE.T_world_camera)
    assert T is SIDE.T_world_camera and table.rig_angle_deg < 0.1
    assert abs(table.rig_offset_m) < 0.001
    # ... and replaces one that does not by the observed plane, keeping the rig's yaw
    T, table = job_frame('auto', tilted)
    assert table.source == 'observed' and table.rig_angle_deg == pytest.approx(3.0, abs=0.1)
    points = np.random.default_rng(0).uniform(-0.1, 0.1, (10, 3)) + [0, 0, 0.6]
    np.testing.assert_allclose(transform_points(T, points)[:, 2],
                               transform_points(SIDE.T_world_camera, points)[:, 2], atol=5e-4)
    assert job_frame('rig', tilted)[0] is tilted


def test_the_plane_is_found_once_per_depth_image(part_on_the_table, monkeypatch):
    from tlessbot_ros.core import pipeline as pipeline_module

    db, depth, labels, _ = part_on_the_table
    calls = []
    find = pipeline_module.find_table_plane
    monkeypatch.setattr(pipeline_module, 'find_table_plane',
                        lambda *a, **k: calls.append(1) or find(*a, **k))
    pipeline = PerceptionPipeline(templates=db)
    views = {'side': ViewInput(None, depth, SIDE.intrinsics)}
    two = labels['side'] * 1
    two[:, :320] *= 2
    pipeline.estimate_poses(views, {'side': two}, {1: 21, 2: 21}, fitter=_Recorder())
    assert len(calls) == 1
    views = {'side': ViewInput(None, depth.copy(), SIDE.intrinsics)}   # the next frame
    pipeline.estimate_poses(views, labels, {1: 21}, fitter=_Recorder())
    assert len(calls) == 2


def test_the_classifier_reads_shapes_in_the_observed_frame(part_on_the_table, monkeypatch):
    from tlessbot_ros.core.recognise import LinearClassifier
    from tlessbot_ros.data import DEFAULT_CLASSIFIER

    _, depth, labels, _ = part_on_the_table
    classifier = LinearClassifier.load(DEFAULT_CLASSIFIER)
    assert classifier.uses_depth
    frames = []
    describe = LinearClassifier.describe

    def spy(self, *args, **kwargs):
        frames.append(kwargs.get('T_world_camera'))
        return describe(self, *args, **kwargs)
    monkeypatch.setattr(LinearClassifier, 'describe', spy)
    rgb = np.full(depth.shape + (3,), 128, np.uint8)
    views = {'side': ViewInput(rgb, depth, SIDE.intrinsics)}      # no extrinsics
    guesses = PerceptionPipeline(classifier=classifier).classify({'side': rgb}, labels,
                                                                 views=views)
    assert set(guesses) == {1}
    [T] = frames
    points = np.random.default_rng(0).uniform(-0.1, 0.1, (10, 3)) + [0, 0, 0.6]
    np.testing.assert_allclose(transform_points(T, points)[:, 2],
                               transform_points(SIDE.T_world_camera, points)[:, 2], atol=5e-4)
