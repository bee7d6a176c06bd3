"""Threads registered with nodes/exit_wait.py: a normal exit asks them to stop and waits for
them; a node's exit through ``os._exit`` (run_node) asks and waits for none."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.ros   # nodes/ imports rclpy

_EXIT = """
import sys
import threading

from tlessbot_ros.nodes.exit_wait import wait_at_exit
from tlessbot_ros.nodes.spin import exit_without_teardown

told = threading.Event()


def stop():
    print('asked to stop', flush=True)
    told.set()


thread = threading.Thread(target=told.wait, daemon=True)
thread.start()
wait_at_exit(thread, stop=stop)
if sys.argv[1] == 'os_exit':
    exit_without_teardown(0)
"""


@pytest.mark.parametrize(('how', 'said'), [('normal', 'asked to stop\n'), ('os_exit', '')])
def test_a_normal_exit_stops_the_threads_and_os_exit_leaves_them(how, said):
    repo = Path(__file__).resolve().parents[2]
    done = subprocess.run([sys.executable, '-c', _EXIT, how], cwd=repo, capture_output=True,
                          text=True, timeout=300)
    assert (done.returncode, done.stdout) == (0, said), done.stderr[-2000:]
