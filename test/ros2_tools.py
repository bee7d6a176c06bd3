"""The real jazzy ``ros2`` command line and ``ros2 launch`` in tests.

They come from ``../shared/ros2-cli`` (``scripts/setup.sh`` installs them into the venv beside
this Python). A test that needs them uses the :data:`needs_ros2` marker: skipped on a clone
without them, never in CI, where a missing CLI must fail the test.

Every call runs without the ros2 daemon (``--no-daemon`` where the verb has it), so no
process outlives a test and no daemon of another ROS_DOMAIN_ID answers.
"""
from __future__ import annotations

import os
import subprocess
import sys
from collections.abc import Sequence
from pathlib import Path

import pytest

ROS2 = Path(sys.executable).with_name('ros2')
VENV_PREFIX = Path(sys.executable).parents[1]
IN_CI = os.environ.get('CI', '').lower() in ('1', 'true', 'yes')


def ros2_available() -> bool:
    if not ROS2.is_file():
        return False
    try:
        import launch_ros  # noqa: F401
        import ros2cli  # noqa: F401
    except ImportError:
        return False
    return True


needs_ros2 = pytest.mark.skipif(
    not IN_CI and not ros2_available(),
    reason='the ros2 command line is not installed (scripts/setup.sh installs it from '
           '../shared/ros2-cli)')


def ros2_env(*prefixes: Path, base: dict[str, str] | None = None) -> dict[str, str]:
    """The environment of a ros2 call: this test run's ROS_DOMAIN_ID and discovery range,
    AMENT_PREFIX_PATH holding ``prefixes`` (e.g. a colcon ``install/tlessbot_ros``) and the
    venv (where the message packages' ament index lives)."""
    env = dict(os.environ if base is None else base)
    known = [str(p) for p in prefixes] + [str(VENV_PREFIX)]
    existing = [p for p in env.get('AMENT_PREFIX_PATH', '').split(os.pathsep) if p]
    env['AMENT_PREFIX_PATH'] = os.pathsep.join(dict.fromkeys(known + existing))
    env['ROS_DISTRO'] = 'jazzy'
    env['PYTHONUNBUFFERED'] = '1'
    return env


def run_ros2(args: Sequence[str], *, timeout_s: float = 60.0,
             env: dict[str, str] | None = None, check: bool = False
             ) -> subprocess.CompletedProcess:
    """``ros2 ARGS`` to completion, output captured as text."""
    result = subprocess.run([str(ROS2), *args], capture_output=True, text=True,
                            timeout=timeout_s, env=env or ros2_env())
    if check and result.returncode != 0:
        raise AssertionError(f'ros2 {" ".join(args)} exited {result.returncode}:\n'
                             f'{result.stdout}\n{result.stderr}')
    return result


def start_ros2(args: Sequence[str], *, env: dict[str, str] | None = None) -> subprocess.Popen:
    """``ros2 ARGS`` in the background (``ros2 launch``, ``ros2 run``), stdout and stderr
    merged into one text pipe; stop it with :func:`stop`."""
    return subprocess.Popen([str(ROS2), *args], stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, env=env or ros2_env(),
                            start_new_session=True)


def stop(process: subprocess.Popen, timeout_s: float = 20.0) -> str:
    """SIGINT the process group (as Ctrl-C in a terminal), then kill stragglers; its output."""
    import signal

    if process.poll() is None:
        try:
            os.killpg(process.pid, signal.SIGINT)
        except ProcessLookupError:
            pass
    try:
        out, _ = process.communicate(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        os.killpg(process.pid, signal.SIGKILL)
        out, _ = process.communicate(timeout=10)
    return out or ''
