"""A stage node's frame thread: the warm-up runs where the frames will (so the first frame
finds that thread's memory grown and buffers made), tools run jobs there between frames, and
a node destroyed during its warm-up does not wait for it."""
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
