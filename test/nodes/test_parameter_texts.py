"""Parameter descriptions are for operators: what the parameter does, its unit and range,
whether it changes live; at most two short lines, and no benchmark figures or history (those
live in docs/bench/parameter-notes.md). Every node is built in-process, no graph needed."""
from __future__ import annotations

import re
import textwrap

import pytest

LINE = 100          # columns of a line
MAX_LINES = 2
# What a lab note looks like: figures of a benchmark, its history and where it was measured.
LAB_NOTE = re.compile('|'.join((
    r'\bp\d\d\b',                   # p95, p50
    r'\bms against\b',
    r'\bagainst \d',                # 0.957 against 0.941
    r'%',
    r'×',
    r'\d\s*->\s*\d',                # 20.6 -> 16.4
    r'\b\d+(\.\d+)?\s*x\b',          # 1.04 x the frames
    r'\b20\d\d-\d\d-\d\d\b',        # dates
    r'\b(session|issue) \d+',
    r'\bseeds? \d+',
    r'\bon \d+ \w+',                # on 60 simulated side views
    r'docs/bench|scripts/|bench \w+',
    r'\bpaired\b',
    r'\bformer(ly)?\b|\bbefore session\b|\bthe previous packaged\b',
)), re.IGNORECASE)


def lab_note(description: str) -> str | None:
    """Why ``description`` is not an operator's text (None when it is one)."""
    lines = textwrap.wrap(description, LINE)
    if len(lines) > MAX_LINES:
        return f'{len(lines)} lines of {LINE} columns (at most {MAX_LINES})'
    found = LAB_NOTE.search(description)
    if found:
        return f'a benchmark figure or history: {found.group(0)!r}'
    if not description.strip():
        return 'empty'
    return None


@pytest.mark.parametrize('text', [
    # lab notes that parameter descriptions carried (now in docs/bench/parameter-notes.md)
    '0.9 rather than 0.95: on 542 simulated parts 1.23 instead of 1.49 fits per part; in paired '
    '60 s runs p95 133-145 against 141-156 ms.',
    'OpenCV releases the GIL: 20.6 -> 16.4 ms per frame for both views on 2 cores.',
    'Paired 30 fps runs: 1.04-1.06 x the frames answered (docs/bench/backpressure.md).',
    'about +25 % pose-stage CPU per frame (session 12)',
    ' '.join(['a long text'] * 30),
])
def test_a_lab_note_is_refused(text):
    assert lab_note(text) is not None


@pytest.mark.parametrize('text', [
    "Largest stamp difference within one camera's colour / depth / camera_info set, s (>= 0). "
    '(live: a change applies at once)',
    "QoS of the subscriptions: 'sensor_data' or 'reliable'. (read-only: set it at start-up)",
])
def test_an_operator_text_passes(text):
    assert lab_note(text) is None


@pytest.fixture(scope='module')
def small_templates(part21_seen_from_the_side, tmp_path_factory):
    path = tmp_path_factory.mktemp('texts') / 'templates.npz'
    part21_seen_from_the_side[0].save(path)
    return path


@pytest.mark.ros
def test_every_parameter_description_is_an_operators_text(small_templates, monkeypatch):
    import rclpy
    from rclpy.parameter import Parameter

    from tlessbot_ros.nodes.camera_driver import CameraDriverNode
    from tlessbot_ros.nodes.classifier import ClassifierNode
    from tlessbot_ros.nodes.foxglove_view import FoxgloveViewNode
    from tlessbot_ros.nodes.localiser import LocaliserNode
    from tlessbot_ros.nodes.objects import ObjectsNode
    from tlessbot_ros.nodes.pose_estimator import PoseEstimatorNode
    from tlessbot_ros.sensors import realsense

    monkeypatch.setattr(realsense, 'connected_serials', lambda: [])
    rclpy_own = {'use_sim_time', 'start_type_description_service'}
    bad, seen = [], 0
    rclpy.init()
    try:
        for make in (LocaliserNode, ClassifierNode, CameraDriverNode, ObjectsNode,
                     lambda: FoxgloveViewNode(parameter_overrides=[Parameter('port', value=0)]),
                     lambda: PoseEstimatorNode(parameter_overrides=[
                         Parameter('templates_path', value=str(small_templates))])):
            node = make()
            try:
                for name in sorted(set(node._parameters) - rclpy_own):
                    seen += 1
                    reason = lab_note(node.describe_parameter(name).description)
                    if reason is not None:
                        bad.append(f'{node.get_name()} {name}: {reason}')
            finally:
                node.destroy_node()
    finally:
        rclpy.try_shutdown()
    assert seen > 150
    assert not bad, '\n'.join(bad)
