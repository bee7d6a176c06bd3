"""The recognition-by-fit settings are node parameters, off by default, from the core
dataclasses, with short descriptions; a bad value is refused live."""
from __future__ import annotations

import pytest

from tlessbot_ros.core.params import ClassifyParams, FitParams

pytestmark = pytest.mark.ros


@pytest.fixture
def ros():
    import rclpy

    rclpy.init()
    yield
    rclpy.try_shutdown()


def test_the_nodes_declare_the_fit_ranking_parameters_off_by_default(ros):
    from rclpy.parameter import Parameter

    from tlessbot_ros.nodes.classifier import ClassifierNode
    from tlessbot_ros.nodes.pose_estimator import PoseEstimatorNode

    classifier = ClassifierNode()
    try:
        assert classifier.classify_params == ClassifyParams()
        assert classifier.candidates == ClassifyParams().class_candidates   # 16UC3 as before
        for name in ('fit_rank_below_margin', 'fit_rank_max_candidates'):
            assert classifier.get_parameter(name).value == getattr(ClassifyParams(), name)
            text = classifier.describe_parameters([name])[0].description
            assert 'fit' in text and len(text) < 250
        refused = classifier.set_parameters([Parameter('fit_rank_below_margin', value=-1.0)])
        assert not refused[0].successful and 'fit_rank_below_margin' in refused[0].reason
    finally:
        classifier.destroy_node()
    # with fit ranking on, unsure parts send up to 4 candidates (16UC4), the most an image holds
    unsure = ClassifierNode(parameter_overrides=[Parameter('fit_rank_below_margin', value=1.0)])
    try:
        assert unsure.candidates == 4 and unsure.classify_params.fit_rank_below_margin == 1.0
    finally:
        unsure.destroy_node()
    pose = PoseEstimatorNode(parameter_overrides=[
        Parameter('workers.count', value=0), Parameter('fit_rank_min_fitness', value=0.4)])
    try:
        assert pose.get_parameter('fit_rank_coverage_weight').value == \
            FitParams().fit_rank_coverage_weight
        assert pose.pipeline.fit_params.fit_rank_min_fitness == 0.4
    finally:
        pose.destroy_node()
