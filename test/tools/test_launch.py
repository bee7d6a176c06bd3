"""launch: process list, one-line errors, a dying node stops the graph."""
import subprocess
import sys
from pathlib import Path

import pytest

from tlessbot_ros.errors import TlessbotError
from tlessbot_ros.io.config import default_config_path
from tlessbot_ros.tools.support.processes import GraphProcesses, ProcessSpec, graph_processes


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


@pytest.mark.parametrize('how', ['SIGTERM', 'SIGINT'])
def test_launch_stops_its_nodes_when_it_is_stopped(how, tmp_path):
    """systemd and docker stop send SIGTERM; a shell's background job ignores SIGINT unless
    launch handles it. Either way no node may outlive launch."""
    import os
    import signal
    import time

    script = tmp_path / 'child.py'     # stands in for a node: it prints its pid and waits
    script.write_text('import os, time\nprint(os.getpid(), flush=True)\ntime.sleep(120)\n')
    code = ('import sys\nfrom tlessbot_ros.tools.commands import launch\n'
            'from tlessbot_ros.tools.support.processes import ProcessSpec\n'
            'launch.graph_processes = lambda *a, **k: [ProcessSpec("fake", '
            f'[sys.executable, {str(script)!r}])]\n'
            'from tlessbot_ros.tools.cli import main\nsys.exit(main(["launch"]))\n')
    process = subprocess.Popen([sys.executable, '-c', code], stdout=subprocess.PIPE, text=True,
                               preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_IGN))
    try:
        assert 'launched 1 processes' in process.stdout.readline()
        child_pid = int(process.stdout.readline().split()[-1])
        os.kill(process.pid, getattr(signal, how))
        assert process.wait(timeout=20) == 0
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline and os.path.exists(f'/proc/{child_pid}'):
            time.sleep(0.1)
        alive = os.path.exists(f'/proc/{child_pid}') and \
            open(f'/proc/{child_pid}/stat').read().split()[2] != 'Z'
        assert not alive
    finally:
        process.kill()
