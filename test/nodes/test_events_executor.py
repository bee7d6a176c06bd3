"""The EventsExecutor as the nodes spin it survives entities created by another thread.

A stage node subscribes on its warm-up thread while its executor spins; rclpy's own
``EventsExecutor.spin()`` stalls holding the interpreter lock when that happens (and never
fires a timer), so every node spins it through ``spin_until_interrupted`` (``spin_once`` with
a timeout). The check runs in a child process killed after a timeout: a stall there holds the
lock, so it could not be detected from inside.
"""
import subprocess
import sys
from pathlib import Path

CHECK = Path(__file__).resolve().parents[2] / 'scripts' / 'events_executor_check.py'


def test_the_nodes_spin_loop_keeps_running_while_another_thread_creates_entities():
    try:
        result = subprocess.run([sys.executable, str(CHECK), '--how', 'spin_once',
                                 '--entities', '300', '--stall-s', '30'],
                                capture_output=True, text=True, timeout=180)
    except subprocess.TimeoutExpired as expired:
        raise AssertionError(f'the spin loop stalled: {expired.stdout!r}') from None
    assert result.returncode == 0, result.stdout + result.stderr
    assert 'spin_once: ok, 300 of 300 pairs created' in result.stdout
