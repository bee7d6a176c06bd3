"""sync.max_rate_hz: a stage drops (and counts) frames that complete too soon after the last."""
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
        node = Counting(parameter_overrides=[Parameter('sync.max_rate_hz', value=5.0)])
        node._on_views({})
        node._on_views({})                   # 0.2 s have not passed: dropped
        assert (node.processed, node.rate_dropped, node.frames) == (1, 1, 1)
        time.sleep(0.25)
        node._on_views({})
        assert (node.processed, node.rate_dropped, node.frames) == (2, 1, 2)
        node.destroy_node()
    finally:
        rclpy.try_shutdown()
