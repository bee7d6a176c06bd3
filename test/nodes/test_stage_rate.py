"""How a stage node admits frames: sync.max_rate_hz drops (and counts) frames that complete too
soon after the last; with sync.worker_thread a busy stage keeps only the newest pending frame."""
from __future__ import annotations

import time

import pytest

pytestmark = pytest.mark.ros


def test_frames_faster_than_max_rate_are_dropped_and_counted():
    import rclpy
    from rclpy.parameter import Parameter

    from tlessbot_ros.nodes.stage import StageNode

    class Counting(StageNode):
        def __init__(self, **kwargs):
            super().__init__('rate_probe', **kwargs)
            self.processed = 0

        def process(self, views):
            self.processed += 1

    rclpy.init()
    try:
        node = Counting(parameter_overrides=[Parameter('sync.max_rate_hz', value=5.0),
                                             Parameter('sync.worker_thread', value=False)])
        node._on_views({})
        node._on_views({})                   # 0.2 s have not passed: dropped
        assert (node.processed, node.rate_dropped, node.frames) == (1, 1, 1)
        assert node.diagnostics_report()[2]['dropped'] == 1   # /diagnostics counts it too
        time.sleep(0.25)
        node._on_views({})
        assert (node.processed, node.rate_dropped, node.frames) == (2, 1, 2)
        node.destroy_node()
    finally:
        rclpy.try_shutdown()


def test_busy_worker_processes_the_newest_frame_and_drops_the_ones_between():
    import threading

    import rclpy

    from tlessbot_ros.nodes.stage import StageNode

    release = threading.Event()

    class Slow(StageNode):
        def __init__(self, **kwargs):
            super().__init__('worker_probe', **kwargs)
            self.seen = []

        def process(self, views):
            self.seen.append(views['top']['n'])
            release.wait(timeout=10.0)

    rclpy.init()
    try:
        node = Slow()
        node._on_views({'top': {'n': 0}})
        deadline = time.monotonic() + 5.0
        while not node.seen and time.monotonic() < deadline:
            time.sleep(0.01)
        for n in (1, 2, 3):        # arrive while frame 0 is being processed
            node._on_views({'top': {'n': n}})
        release.set()
        assert node.wait_idle(10.0)
        assert node.seen == [0, 3]
        assert (node.frames, node.busy_dropped) == (2, 2)
        node.destroy_node()
    finally:
        rclpy.try_shutdown()


def test_frames_released_at_a_time_jump_are_all_processed_in_order():
    """Frames held while a time jump waited for confirmation come together; none is replaced
    by the next, and the max rate does not drop them."""
    import threading

    import rclpy
    from rclpy.parameter import Parameter

    from tlessbot_ros.nodes.stage import StageNode

    release = threading.Event()

    class Slow(StageNode):
        def __init__(self, **kwargs):
            super().__init__('held_probe', **kwargs)
            self.seen = []

        def process(self, views):
            self.seen.append(views['top']['n'])
            release.wait(timeout=10.0)

    rclpy.init()
    try:
        node = Slow(parameter_overrides=[Parameter('sync.max_rate_hz', value=1.0)])
        node._on_views({'top': {'n': 0}})
        deadline = time.monotonic() + 5.0
        while not node.seen and time.monotonic() < deadline:
            time.sleep(0.01)
        node._on_views({'top': {'n': 1}}, True)     # released together at a jump
        node._on_views({'top': {'n': 2}}, True)
        node._on_views({'top': {'n': 3}})           # the next frame: within 1 s, dropped
        release.set()
        assert node.wait_idle(10.0)
        assert node.seen == [0, 1, 2]
        assert (node.frames, node.busy_dropped, node.rate_dropped) == (3, 0, 1)
        node.destroy_node()
    finally:
        rclpy.try_shutdown()
