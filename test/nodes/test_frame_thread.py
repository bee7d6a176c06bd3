"""A stage node's frame thread: the warm-up runs where the frames will (so the first frame
finds that thread's memory grown and buffers made), tools run jobs there between frames, and
a node destroyed during its warm-up does not wait for it; the interpreter's exit does."""
from __future__ import annotations

import threading

import pytest

pytestmark = pytest.mark.ros


def _probe_class():
    from tlessbot_ros.nodes.stage import StageNode

    class Probe(StageNode):
        def __init__(self, **kwargs):
            super().__init__('frame_thread_probe', **kwargs)
            self.process_threads = []

        def process(self, views):
            self.process_threads.append(threading.get_ident())

    return Probe


# one input topic per camera: the node subscribes once ready
TOPICS = {'color': ('sensor_msgs/msg/Image', lambda camera: f'/frame_thread_probe/{camera}')}


@pytest.fixture
def ros():
    import rclpy
    rclpy.init()
    yield
    rclpy.try_shutdown()


def test_the_warm_up_runs_on_the_thread_that_processes_the_frames(ros):
    node = _probe_class()()
    warm_threads = []
    node.start_when_ready(lambda: warm_threads.append(threading.get_ident()), TOPICS)
    assert node.wait_ready(30.0)
    node._on_views({'top': {'n': 0}})
    assert node.wait_idle(10.0)
    assert node.process_threads == warm_threads
    assert warm_threads[0] != threading.get_ident()
    node.destroy_node()


def test_a_job_on_the_frame_thread_returns_its_result_or_its_error(ros):
    node = _probe_class()()
    assert node.on_frame_thread(lambda: threading.get_ident()).result(10.0) == node._worker.ident

    def fails():
        raise ValueError('bad job')
    with pytest.raises(ValueError, match='bad job'):
        node.on_frame_thread(fails).result(10.0)
    node.destroy_node()


def test_without_a_worker_thread_a_job_runs_on_a_thread_of_its_own(ros):
    from rclpy.parameter import Parameter

    node = _probe_class()(parameter_overrides=[Parameter('sync.worker_thread', value=False)])
    ident = node.on_frame_thread(lambda: threading.get_ident()).result(10.0)
    assert ident != threading.get_ident()
    node.destroy_node()


def test_a_node_destroyed_during_its_warm_up_does_not_wait_and_never_gets_ready(ros):
    node = _probe_class()()
    started, release = threading.Event(), threading.Event()

    def slow_warm_up():
        started.set()
        release.wait(30.0)
    node.start_when_ready(slow_warm_up, TOPICS)
    assert started.wait(10.0)
    queued = node.on_frame_thread(lambda: 'never')
    node.destroy_node()                       # returns while the warm-up still runs
    assert not release.is_set() and node._worker.is_alive()
    assert queued.cancelled()
    release.set()
    node._worker.join(10.0)
    assert not node._worker.is_alive()
    assert not node.ready.is_set()            # it saw the node stopping: no subscriptions



# A frame thread still in OpenCV (numba's compiler is alike) while the interpreter exits.
_EXIT_DURING_A_JOB = """
import sys
import threading

import cv2
import numpy as np

from tlessbot_ros.nodes.frame_worker import FrameWorker

worker = FrameWorker('exit_probe', handle=lambda views: None, before_frame=lambda: None)
started = threading.Event()
image = np.zeros((1000, 1000), np.uint8)


def work_past_the_exit():   # the node was destroyed during its warm-up
    started.set()
    threading.main_thread().join()   # returns once the interpreter's exit has begun
    for _ in range(50):
        cv2.connectedComponentsWithStats(image)   # each call releases the GIL
    print('job finished', flush=True)


def work_until_stopped():   # a node never destroyed
    started.set()
    while not worker.stopping:
        cv2.connectedComponentsWithStats(image)
    print('job finished', flush=True)


worker.on_frame_thread(work_until_stopped if sys.argv[1] == 'never' else work_past_the_exit)
started.wait()
if sys.argv[1] == 'during_its_job':
    worker.stop(join=False)   # what destroying a node during its warm-up does
"""


@pytest.mark.parametrize('destroyed', ['during_its_job', 'never'])
def test_the_process_exits_after_the_frame_threads_job_not_during_it(destroyed):
    """Cut off at exit, the thread never finishes its job, or the process aborts (SIGABRT,
    "FATAL: exception not rethrown") when OpenCV's binding catches the thread's unwind."""
    import subprocess
    import sys
    from pathlib import Path

    repo = Path(__file__).resolve().parents[2]
    done = subprocess.run([sys.executable, '-c', _EXIT_DURING_A_JOB, destroyed], cwd=repo,
                          capture_output=True, text=True, timeout=300)
    assert (done.returncode, done.stdout) == (0, 'job finished\n'), done.stderr[-2000:]
