"""tlessbot bench nodes: every stage node's process() timed on the demo bag's frames."""
import pytest

from tlessbot_ros.tools.cli import main

pytestmark = [pytest.mark.ros, pytest.mark.rosbag]


def test_bench_nodes_times_every_stage_on_the_demo_bag(capsys):
    assert main(['bench', 'nodes', '--repeats', '1']) == 0
    out = capsys.readouterr().out
    rows = {line.split('|')[1].strip(): float(line.split('|')[2])
            for line in out.splitlines() if line.startswith('| ') and 'median' not in line}
    assert set(rows) == {'localiser', 'classifier', 'pose_estimator'}
    assert all(ms > 0 for ms in rows.values())
    assert '6 frames x 1 passes' in out
