"""launch: process list, one-line errors, a dead node started again (or, when it
cannot be, the graph stopped)."""
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
    assert specs[0].argv[-6:] == ['--rate', '0.5', '--wait-for-subscribers', '10', '--loop',
                                  '--restamp']


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


def _launch_fake_node(tmp_path: Path, child_code: str, *launch_args: str) -> subprocess.Popen:
    """``tlessbot launch`` running one stand-in process 'fake' (``child_code``; no stage node,
    so no ROS) in place of the graph, with SIGINT ignored as in a shell's background job."""
    import signal

    script = tmp_path / 'child.py'
    script.write_text(child_code)
    code = ('import sys\nfrom tlessbot_ros.tools.commands import launch\n'
            'from tlessbot_ros.tools.support.processes import ProcessSpec\n'
            'launch.graph_processes = lambda *a, **k: [ProcessSpec("fake", '
            f'[sys.executable, {str(script)!r}])]\n'
            'from tlessbot_ros.tools.cli import main\n'
            f'sys.exit(main(["launch", *{list(launch_args)!r}]))\n')
    return subprocess.Popen([sys.executable, '-c', code], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_IGN))


PRINT_PID_AND_WAIT = 'import os, time\nprint(os.getpid(), flush=True)\ntime.sleep(120)\n'


def _wait_gone(pid: int, timeout_s: float = 10.0) -> bool:
    """True once ``pid`` is gone or a zombie."""
    import os
    import time

    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if not os.path.exists(f'/proc/{pid}') or \
                open(f'/proc/{pid}/stat').read().rsplit(')', 1)[1].split()[0] == 'Z':
            return True
        time.sleep(0.1)
    return False


@pytest.mark.parametrize('how', ['SIGTERM', 'SIGINT'])
def test_launch_stops_its_nodes_when_it_is_stopped(how, tmp_path):
    """systemd and docker stop send SIGTERM; a shell's background job ignores SIGINT unless
    launch handles it. Either way no node may outlive launch."""
    import os
    import signal

    process = _launch_fake_node(tmp_path, PRINT_PID_AND_WAIT)
    try:
        assert 'launched 1 processes' in process.stdout.readline()
        child_pid = int(process.stdout.readline().split()[-1])
        os.kill(process.pid, getattr(signal, how))
        assert process.wait(timeout=20) == 0
        assert _wait_gone(child_pid)
    finally:
        process.kill()


def test_a_killed_node_is_started_again(tmp_path):
    import os
    import signal

    process = _launch_fake_node(tmp_path, PRINT_PID_AND_WAIT, '--respawn-delay', '0.1')
    try:
        assert 'launched 1 processes' in process.stdout.readline()
        first_pid = int(process.stdout.readline().split()[-1])
        os.kill(first_pid, signal.SIGKILL)
        lines = [process.stdout.readline() for _ in range(3)]
        assert lines[0].startswith('[launch] fake exited with code -9 (SIGKILL); restarting '
                                   'it in 0.1 s'), lines
        assert '[launch] fake restarted (exit -9)\n' in lines[1:], lines
        second_pid = int(next(line for line in lines if line.startswith('[fake]')).split()[-1])
        assert second_pid != first_pid
        os.kill(process.pid, signal.SIGTERM)
        assert process.wait(timeout=20) == 0
        assert _wait_gone(second_pid)
    finally:
        process.kill()


def test_a_crash_loop_stops_the_graph_with_one_clear_line(tmp_path):
    process = _launch_fake_node(tmp_path, 'print("starting", flush=True)\nraise SystemExit(3)\n',
                                '--respawn-delay', '0.05', '--max-restarts', '2')
    out, err = process.communicate(timeout=60)
    assert process.returncode == 1
    assert out.count('[fake] starting') == 3, out   # the first start and two restarts
    assert err.strip().splitlines()[-1] == (
        '[launch] ERROR: fake exited with code 3; not restarted: it was restarted 2 times '
        'within 600 s; stopping the graph')


def test_without_respawn_a_death_stops_the_graph(tmp_path):
    process = _launch_fake_node(tmp_path, 'raise SystemExit(3)\n', '--no-respawn')
    out, err = process.communicate(timeout=60)
    assert process.returncode == 1
    assert 'restarting' not in out
    assert 'fake exited with code 3; not restarted: respawn is off' in err


def test_bad_respawn_options_are_one_line():
    result = subprocess.run([sys.executable, '-m', 'tlessbot_ros.tools.cli', 'launch',
                             '--respawn-delay', '0'], capture_output=True, text=True)
    assert result.returncode == 1
    assert result.stderr.startswith('tlessbot launch: error: the respawn delay must be > 0')


def test_a_process_is_restarted_under_its_label():
    graph = GraphProcesses([ProcessSpec('short', [sys.executable, '-c', 'print("hi")'])])
    sink: list[str] = []
    graph.start_capturing(sink)
    try:
        first = graph.children['short']
        first.wait(timeout=30)
        started = graph.started['short']
        assert graph.exited() == [('short', 0)]
        second = graph.restart('short')
        assert graph.children['short'] is second and second.pid != first.pid
        assert graph.started['short'] > started
        second.wait(timeout=30)
        graph.stop(timeout_s=5)
        assert sink.count('[short] hi\n') == 2
    finally:
        graph.stop(timeout_s=5)


def test_a_running_process_is_not_restarted():
    graph = GraphProcesses([ProcessSpec('sleeper', [sys.executable, '-c',
                                                    'import time; time.sleep(60)'])])
    graph.start_capturing([])
    try:
        with pytest.raises(RuntimeError, match='still running'):
            graph.restart('sleeper')
    finally:
        graph.stop(timeout_s=5)



def test_the_graphs_children_run_this_processs_tlessbot_ros_wherever_they_start(tmp_path):
    """A child started in a directory holding another tlessbot_ros (a source checkout, while
    this process runs a tree on PYTHONPATH) imports this process's package, not that one."""
    import os

    import tlessbot_ros
    from tlessbot_ros.tools.support.processes import same_code_env

    (tmp_path / 'tlessbot_ros').mkdir()
    (tmp_path / 'tlessbot_ros' / '__init__.py').write_text('')
    env = same_code_env({**os.environ, 'PYTHONPATH': '/nowhere'})
    assert env['PYTHONPATH'].split(os.pathsep)[-1] == '/nowhere'   # kept, after ours
    printed = subprocess.run([sys.executable, '-c',
                              'import tlessbot_ros; print(tlessbot_ros.__file__)'],
                             cwd=tmp_path, env=env, capture_output=True, text=True, check=True)
    assert printed.stdout.strip() == tlessbot_ros.__file__
    plain = {k: v for k, v in os.environ.items() if k != 'PYTHONSAFEPATH'}
    shadowed = subprocess.run([sys.executable, '-c',
                               'import tlessbot_ros; print(tlessbot_ros.__file__)'],
                              cwd=tmp_path, env=plain, capture_output=True, text=True,
                              check=True)
    assert shadowed.stdout.strip() != tlessbot_ros.__file__   # what it guards against
