"""launch: process list, one-line errors, a dying node stops the graph."""
import subprocess
import sys
from pathlib import Path

import pytest

from tlessbot_ros.errors import TlessbotError
from tlessbot_ros.io.config import default_config_path
from tlessbot_ros.tools.launch import GraphProcesses, ProcessSpec, graph_processes


def test_camera_drivers_are_namespaced_per_camera():
    specs = graph_processes(default_config_path(), nodes=['camera_driver'])
    assert [s.label for s in specs] == ['camera_driver/top', 'camera_driver/side']
    top = specs[0].argv
    assert '--params-file' in top and str(default_config_path()) in top
    assert top[top.index('-r') + 1] == '__ns:=/top'
    assert 'camera_name:=top' in top


def test_replay_replaces_the_drivers():
    specs = graph_processes(Path('cell.yaml'), replay='bag.mcap', rate=0.5, loop=True,
                            nodes=['camera_driver'])
    assert [s.label for s in specs] == ['replay']
    assert specs[0].argv[-5:] == ['--rate', '0.5', '--wait-for-subscribers', '10', '--loop']


def test_unknown_node_is_an_error():
    with pytest.raises(TlessbotError, match="node 'teleporter'"):
        graph_processes(Path('cell.yaml'), nodes=['teleporter'])


def test_a_dying_child_is_reported_and_the_rest_stopped():
    graph = GraphProcesses([
        ProcessSpec('sleeper', [sys.executable, '-c', 'import time; time.sleep(60)']),
        ProcessSpec('crasher', [sys.executable, '-c', 'raise SystemExit(3)'])])
    graph.start()
    try:
        exited = None
        for _ in range(100):
            exited = graph.first_exited()
            if exited:
                break
            subprocess.run(['sleep', '0.05'])
        assert exited == ('crasher', 3)
    finally:
        graph.stop(timeout_s=5)
    assert graph.children['sleeper'].poll() is not None


def test_missing_config_is_one_line():
    result = subprocess.run([sys.executable, '-m', 'tlessbot_ros.tools.cli', 'launch',
                             '--config', '/nonexistent.yaml'], capture_output=True, text=True)
    assert result.returncode == 1
    assert result.stderr.strip() == \
        'tlessbot launch: error: parameter file not found: /nonexistent.yaml'
