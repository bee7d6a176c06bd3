"""tlessbot bench nodes: every stage node's process() timed on the demo bag's frames."""
import pytest

from tlessbot_ros.tools.cli import main

pytestmark = [pytest.mark.ros, pytest.mark.rosbag]


def test_bench_nodes_times_every_stage_on_the_demo_bag(capsys, tmp_path):
    import json

    assert main(['bench', 'nodes', '--repeats', '1', '--json', str(tmp_path / 'stages.json')]) == 0
    out = capsys.readouterr().out
    rows = {line.split('|')[1].strip(): float(line.split('|')[2])
            for line in out.splitlines() if line.startswith('| ') and 'median' not in line}
    assert set(rows) == {'localiser', 'classifier', 'pose_estimator'}
    assert all(ms > 0 for ms in rows.values())
    assert '6 frames x 1 passes' in out
    figures = json.loads((tmp_path / 'stages.json').read_text())
    assert set(figures) == set(rows)
    medians = {line.split('|')[1].strip(): float(line.split('|')[3])
               for line in out.splitlines() if line.startswith('| ') and 'median' not in line}
    assert all(f['median_ms'] == pytest.approx(medians[name], abs=0.05)
               and f['cpu_ms_per_frame'] > 0 for name, f in figures.items())


def test_bench_nodes_runs_the_stages_with_the_graphs_parameters(capsys, tmp_path):
    # bench graph compares the graph with its stages alone: both must run the same config
    config = tmp_path / 'one_thread_per_stage.yaml'
    config.write_text('localiser:\n  ros__parameters:\n    parallel_views: false\n'
                      'pose_estimator:\n  ros__parameters:\n    workers:\n      count: 0\n')
    assert main(['bench', 'nodes', '--repeats', '1', '--config', str(config)]) == 0
    assert (f'parameters of {config}: localiser parallel_views False, pose_estimator '
            'workers.count 0.') in capsys.readouterr().out
    assert main(['bench', 'nodes', '--repeats', '1', '--config', str(config),
                 '--pose-workers', '1']) == 0   # the option wins over the config
    assert 'parallel_views False, pose_estimator workers.count 1.' in capsys.readouterr().out


def test_bench_nodes_can_wait_before_each_stage(capsys):
    """--idle-before-ms: the stages' figures after a pause, asleep or spinning."""
    assert main(['bench', 'nodes', '--repeats', '1', '--idle-before-ms', '5']) == 0
    assert "5 ms idle before each stage's frame." in capsys.readouterr().out
    assert main(['bench', 'nodes', '--repeats', '1', '--idle-before-ms', '5',
                 '--idle-busy']) == 0
    out = capsys.readouterr().out
    assert "5 ms spent spinning before each stage's frame." in out
    rows = [line for line in out.splitlines() if line.startswith('| ') and 'median' not in line]
    assert len(rows) == 3 and all(float(row.split('|')[3]) > 0 for row in rows)
