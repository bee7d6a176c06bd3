"""End to end over real processes and DDS: the committed demo bag -> localiser -> classifier ->
pose_estimator -> PoseStamped, compared with the bag's ground truth (5 cm / 5°, symmetry-aware,
right class)."""
import pytest

from tlessbot_ros.data import DEFAULT_CLASSIFIER, DEFAULT_MODELS_INFO, DEFAULT_TEMPLATES
from tlessbot_ros.io.config import default_config_path
from tlessbot_ros.tools.commands.demo import run_demo
from tlessbot_ros.tools.support.defaults import DEFAULT_BAG
from tlessbot_ros.tools.support.models_info import load_symmetries

pytestmark = [pytest.mark.ros, pytest.mark.rosbag, pytest.mark.slow]


def test_demo_bag_through_the_graph(capsys):
    summary = run_demo(str(DEFAULT_BAG), config=default_config_path(),
                       classifier=str(DEFAULT_CLASSIFIER), templates=str(DEFAULT_TEMPLATES),
                       symmetries=load_symmetries(DEFAULT_MODELS_INFO))
    report = capsys.readouterr().out
    assert summary['frames'] >= 3, report
    assert summary['parts_scored'] >= 10, report
    # Issue 7's bar: >= 90 % within 5 cm / 5 deg with the right class. Measured 25/27 = 0.926
    # on this bag (lock-step replay, deterministic), with the pose fit verifying the classifier's
    # top 3; the classifier alone gave 23/27.
    assert summary['recall_5cm5deg'] >= 0.90, report
    assert summary['false_positives'] <= summary['parts_scored'] // 4, report
