"""Recognition by fit where the classifier is unsure (core/by_fit.py, PerceptionPipeline)."""
from __future__ import annotations

import numpy as np
import pytest

from tlessbot_ros.core.by_fit import candidate_channels, fit_ranked, ranking_depth
from tlessbot_ros.core.common import default_rig
from tlessbot_ros.core.pipeline import ClassifyParams, FitParams, PerceptionPipeline, ViewInput
from tlessbot_ros.core.recognise import UNKNOWN_ID, HogParams, LinearClassifier

SIDE = default_rig()['side']


def _unsure_classifier(first: int, second: int, margin: float) -> LinearClassifier:
    """A model that names ``first`` whatever it sees, ``margin`` above ``second`` (median
    training margin 1)."""
    return LinearClassifier(np.zeros((HogParams().feature_dim, 2), np.float32),
                            np.array([margin, 0.0], np.float32), np.array([first, second]),
                            margin_scale=1.0)


@pytest.fixture(scope='module')
def part21(part21_seen_from_the_side):
    """Part 21 on the table seen by the side camera; templates of parts 5 and 21."""
    db, depth, mask, T_camera_object = part21_seen_from_the_side
    depth = depth + np.random.default_rng(1).normal(0, 0.0005, depth.shape).astype(
        np.float32) * (depth > 0)
    rgb = np.full((*depth.shape, 3), 90, np.uint8)
    rgb[mask] = 200
    views = {'side': ViewInput(rgb, depth, SIDE.intrinsics, SIDE.T_world_camera)}
    return db, views, {'side': mask.astype(np.uint16)}, T_camera_object


def _name(pipeline: PerceptionPipeline, views, labels):
    guesses = pipeline.classify({'side': views['side'].rgb}, labels, views=views)
    # a copy: the pose stage replaces the images by the regions trimmed to their fits, and
    # the fixture's labels serve every test of the module
    detections = pipeline.estimate_poses(views, dict(labels),
                                         {i: g.candidates for i, g in guesses.items()})
    return guesses[1], detections[0]


def test_an_unsure_wrong_first_guess_is_overruled_by_the_part_that_fits(part21):
    db, views, labels, T_gt = part21
    model = _unsure_classifier(5, 21, margin=0.1)
    alone = PerceptionPipeline(classifier=model, templates=db,
                               classify_params=ClassifyParams(class_candidates=1))
    guess, detection = _name(alone, views, labels)
    assert guess.obj_id == 5 and guess.candidates == (5,) and detection.obj_id == 5

    by_fit = alone.replace(classify_params=ClassifyParams(class_candidates=1,
                                                          fit_rank_below_margin=0.5))
    guess, detection = _name(by_fit, views, labels)
    assert guess.obj_id == 5 and guess.candidates == (5, 21)
    assert detection.obj_id == 21 and detection.class_rank == 1
    assert np.linalg.norm(detection.pose.T_camera_object[:3, 3] - T_gt[:3, 3]) < 0.01


def _ranking_by_fit(db, margin: float) -> PerceptionPipeline:
    """Classifier alone (one candidate) unless its margin is below 0.5: then fit ranking."""
    return PerceptionPipeline(
        classifier=_unsure_classifier(5, 21, margin=margin), templates=db,
        classify_params=ClassifyParams(class_candidates=1, fit_rank_below_margin=0.5))


def test_a_sure_classifier_is_not_second_guessed(part21):
    db, views, labels, _ = part21
    guess, detection = _name(_ranking_by_fit(db, 0.8), views, labels)
    assert guess.candidates == (5,) and detection.obj_id == 5


def test_a_part_that_nothing_fits_well_enough_is_unknown(part21):
    db, views, labels, _ = part21
    pipeline = _ranking_by_fit(db, 0.1)
    _, fitted = _name(pipeline, views, labels)
    assert fitted.obj_id == 21 and fitted.pose.fitness < 1.0
    floor = pipeline.replace(fit_params=FitParams(fit_rank_min_fitness=min(
        1.0, fitted.pose.fitness + 0.01)))
    _, detection = _name(floor, views, labels)
    assert detection.obj_id == UNKNOWN_ID and detection.pose is None


def test_off_by_default_the_candidates_are_those_of_before():
    assert ClassifyParams().fit_rank_below_margin == 0 and FitParams().fit_rank_min_fitness == 0
    assert FitParams().fit_rank_coverage_weight == 0
    assert ranking_depth(3, 0.0, 8, 30) == 3
    pipeline = PerceptionPipeline(classifier=_unsure_classifier(7, 4, margin=0.0))
    ranked = [7, 4, 9, 11, 12]
    assert pipeline.verification_candidates(7, 0.0, ranked, 'side') == (7, 4, 9)
    assert pipeline.verification_candidates(7, 0.0, ranked[:3], 'side') == (7, 4, 9)


def test_the_budget_is_a_count_of_candidates():
    ranked = list(range(1, 31))
    assert fit_ranked(0.1, ranked, 1.0, below_margin=0.5, max_candidates=8) == tuple(range(1, 9))
    assert fit_ranked(0.1, ranked, 1.0, below_margin=0.5, max_candidates=0) == tuple(ranked)
    assert fit_ranked(0.6, ranked, 1.0, below_margin=0.5, max_candidates=8) is None
    assert fit_ranked(0.1, ranked, 1.0, below_margin=0.0, max_candidates=8) is None
    assert fit_ranked(0.4, ranked, 0.0, below_margin=0.5, max_candidates=2) == (1, 2)  # no scale
    assert ranking_depth(3, 0.5, 8, 30) == 8 and ranking_depth(3, 0.5, 0, 30) == 30
    assert ranking_depth(3, 0.5, 2, 30) == 3
    assert candidate_channels(3, 0.0, 8) == 3 and candidate_channels(1, 0.0, 0) == 1   # off
    assert candidate_channels(3, 0.5, 8) == 4 and candidate_channels(1, 0.5, 2) == 2
    assert candidate_channels(3, 0.5, 0) == 4   # all parts: as many as an image holds


@pytest.mark.parametrize('params_class, field, value', [
    (ClassifyParams, 'fit_rank_below_margin', -0.1),
    (ClassifyParams, 'fit_rank_max_candidates', -1),
    (FitParams, 'fit_rank_min_fitness', 1.5),
    (FitParams, 'fit_rank_coverage_weight', -1.0),
])
def test_bad_fit_ranking_settings_are_refused(params_class, field, value):
    with pytest.raises(ValueError, match=field):
        params_class(**{field: value})
