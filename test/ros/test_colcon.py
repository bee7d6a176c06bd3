"""The colcon path as a user takes it: `colcon build` a workspace holding this package, source
install/setup.sh, then the real `ros2 pkg`, `ros2 run` and `ros2 launch` act on the installed
copy, and the real `ros2 topic echo --once` gets a pose from the running graph."""
import os
import re
import signal
import subprocess
import threading
import time
from pathlib import Path

import pytest
from ros2_tools import VENV_PREFIX, needs_ros2, ros2_env, run_ros2, start_ros2

pytestmark = [pytest.mark.ros, pytest.mark.slow, needs_ros2]

REPO = Path(__file__).resolve().parents[2]
COLCON = VENV_PREFIX / 'bin' / 'colcon'
# obj_25 is in the demo bag's first two frames; the graph found it in both (tlessbot demo).
POSE_TOPIC = '/objects/obj_25/pose'
EXECUTABLES = ('camera_driver', 'classifier', 'foxglove_view', 'localiser', 'objects',
               'pose_estimator', 'tlessbot')


def user_environment() -> dict[str, str]:
    """A shell with the ROS underlay (here the venv) on PATH and AMENT_PREFIX_PATH, and no
    PYTHONPATH pointing at the source tree: only the installed package may be imported."""
    env = ros2_env(base={k: v for k, v in os.environ.items() if k != 'PYTHONPATH'})
    env['PATH'] = f'{VENV_PREFIX / "bin"}{os.pathsep}{env.get("PATH", "")}'
    return env


@pytest.fixture(scope='module')
def workspace(tmp_path_factory) -> Path:
    """A colcon workspace with this package in src/, built as the README says."""
    root = tmp_path_factory.mktemp('ros2_ws')
    (root / 'src').mkdir()
    (root / 'src' / 'tlessbot_ros').symlink_to(REPO)
    started = time.monotonic()
    build = subprocess.run([str(COLCON), 'build', '--event-handlers', 'console_direct+'],
                           cwd=root, env=user_environment(), capture_output=True, text=True,
                           timeout=900)
    print(f'colcon build: exit {build.returncode} in {time.monotonic() - started:.1f} s')
    assert build.returncode == 0, build.stdout + build.stderr
    return root


@pytest.fixture
def in_workspace(workspace, monkeypatch) -> Path:
    """Commands run from the workspace, as a user's would: from the source tree, ``python -m``
    and ``python -c`` would import its tlessbot_ros instead of the installed one."""
    monkeypatch.chdir(workspace)
    return workspace


@pytest.fixture(scope='module')
def sourced(workspace) -> dict[str, str]:
    """The environment after `source install/setup.sh` (the real script, run by bash)."""
    dump = subprocess.run(['bash', '-c', '. install/setup.sh && env -0'], cwd=workspace,
                          env=user_environment(), capture_output=True, check=True)
    env = dict(line.split('=', 1) for line in dump.stdout.decode().split('\0') if '=' in line)
    assert env['AMENT_PREFIX_PATH'].split(os.pathsep)[0] == str(
        workspace / 'install' / 'tlessbot_ros')
    return env


def test_the_installed_package_is_what_runs(in_workspace, sourced):
    listed = run_ros2(['pkg', 'executables', 'tlessbot_ros'], env=sourced, check=True)
    assert sorted(listed.stdout.split()[1::2]) == list(EXECUTABLES)
    usage = run_ros2(['run', 'tlessbot_ros', 'tlessbot', '--help'], env=sourced, check=True)
    assert 'usage: tlessbot <command>' in usage.stdout
    where = subprocess.run(['python3', '-c', 'import tlessbot_ros; print(tlessbot_ros.__file__)'],
                           env=sourced, capture_output=True, text=True, check=True)
    assert where.stdout.startswith(str(in_workspace / 'install' / 'tlessbot_ros')), where.stdout
    share = run_ros2(['pkg', 'prefix', '--share', 'tlessbot_ros'], env=sourced, check=True)
    installed = Path(share.stdout.strip())
    assert (installed / 'launch' / 'cell.launch.py').is_file()
    assert (installed / 'config' / 'cell.yaml').is_file()


class LaunchOutput:
    """Collects a running `ros2 launch`'s output lines and waits for patterns in them."""

    def __init__(self, process: subprocess.Popen) -> None:
        self.process = process
        self.lines: list[str] = []
        self._changed = threading.Condition()
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        for line in self.process.stdout:
            print(line, end='')   # into the CI log
            with self._changed:
                self.lines.append(line)
                self._changed.notify_all()
        with self._changed:
            self._changed.notify_all()

    def matches(self, pattern: str) -> list[re.Match]:
        with self._changed:
            return [m for line in self.lines if (m := re.search(pattern, line))]

    def wait_for(self, pattern: str, *, count: int = 1, timeout_s: float = 300.0) -> re.Match:
        """The ``count``-th line matching ``pattern``, waiting for it."""
        deadline = time.monotonic() + timeout_s
        with self._changed:
            while len(found := self.matches(pattern)) < count:
                remaining = deadline - time.monotonic()
                assert remaining > 0 and self.process.poll() is None, \
                    f'no {pattern!r} (x{count}) in the launch output:\n' + ''.join(self.lines)
                self._changed.wait(min(remaining, 1.0))
            return found[count - 1]

    def stop(self, timeout_s: float = 30.0) -> int:
        """Ctrl-C (SIGINT to the process group, as a terminal sends it); its exit code."""
        if self.process.poll() is None:
            os.killpg(self.process.pid, signal.SIGINT)
        try:
            code = self.process.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            os.killpg(self.process.pid, signal.SIGKILL)
            code = self.process.wait(timeout=10)
        self._reader.join(timeout=10)
        return code


def echo_pose(env: dict[str, str]) -> str:
    """One PoseStamped from the running graph, by the real `ros2 topic echo --once`."""
    result = run_ros2(['topic', 'echo', '--once', '--no-daemon', POSE_TOPIC,
                       'geometry_msgs/msg/PoseStamped'], env=env, timeout_s=600, check=True)
    return result.stdout


@pytest.mark.timeout(1200)   # a fresh install compiles its numba kernels once (warm-up)
def test_launch_replays_the_demo_bag_into_poses_and_respawns_a_dead_stage(in_workspace, sourced):
    warm = run_ros2(['run', 'tlessbot_ros', 'tlessbot', 'warm-up'], env=sourced,
                    timeout_s=900, check=True)
    print(warm.stdout)
    share = run_ros2(['pkg', 'prefix', '--share', 'tlessbot_ros'], env=sourced, check=True)
    bag = Path(share.stdout.strip()) / 'bags' / 'demo'
    started = time.monotonic()
    launch = LaunchOutput(start_ros2(['launch', 'tlessbot_ros', 'cell.launch.py',
                                      f'replay:={bag}', 'rate:=0.5', 'loop:=true'],
                                     env=sourced))
    try:
        pose = echo_pose(sourced)
        print(f'first pose {time.monotonic() - started:.1f} s after ros2 launch:\n{pose}')
        assert 'frame_id: side_color_optical_frame' in pose or \
            'frame_id: top_color_optical_frame' in pose
        assert re.search(r'position:\s+x: -?\d', pose)

        # respawn: kill the classifier; launch starts it again and poses resume.
        classifier = launch.wait_for(r'\[(classifier-\d+)\]: process started with pid \[(\d+)\]')
        os.kill(int(classifier.group(2)), signal.SIGKILL)
        label = re.escape(classifier.group(1))
        launch.wait_for(rf'\[{label}\]: process has died')
        launch.wait_for(rf'\[{label}\]: process started with pid', count=2)
        launch.wait_for(r'\[classifier\]: ready', count=2)
        assert 'position:' in echo_pose(sourced)
    finally:
        code = launch.stop()
    pids = [int(m.group(1)) for m in launch.matches(r'process started with pid \[(\d+)\]')]
    output = ''.join(launch.lines)
    assert code == 0, output
    assert not [pid for pid in pids if _alive(pid)], 'processes outlived ros2 launch'
    # Ctrl-C stops every process cleanly (no traceback from launch's second SIGINT).
    stopped = output[output.index('user interrupted with ctrl-c'):]
    # the replay, the three stages and objects
    assert len(re.findall(r'process has finished cleanly', stopped)) == 5, stopped
    assert 'Traceback' not in output
    assert '[FATAL]' not in stopped, stopped   # no callback cut by the signal's interrupt


def _alive(pid: int) -> bool:
    try:
        state = Path(f'/proc/{pid}/stat').read_text().split()[2]
    except FileNotFoundError:
        return False
    return state != 'Z'
