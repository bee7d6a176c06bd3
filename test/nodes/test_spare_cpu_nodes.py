"""The localiser and the pose estimator split a frame's work only while the host has a core to
spare (parallel.min_spare_cores), and give the same answer either way."""
from __future__ import annotations

import pytest

pytestmark = [pytest.mark.ros, pytest.mark.rosbag]


@pytest.fixture
def ros():
    import rclpy

    rclpy.init()
    yield
    rclpy.try_shutdown()


class _Captured:
    def __init__(self):
        self.messages = []

    def publish(self, msg):
        self.messages.append(msg)


def _host(free_cores: float):
    """A SpareCpu over a 2-core host on which ``free_cores`` are always free beside the
    stage's own thread (one core of its own)."""
    from tlessbot_ros.parallel.spare_cpu import SpareCpu, SpareCpuParams

    clock = iter(range(0, 10_000))
    ticks = {'idle': 0, 'total': 0}
    own = iter(range(0, 10_000))

    def counters():
        ticks['idle'] += int(100 * free_cores)
        ticks['total'] += 200
        return ticks['idle'], ticks['total']

    spare = SpareCpu(SpareCpuParams(min_spare_cores=0.5, window_s=0.5), counters=counters,
                     cores=2, clock=lambda: float(next(clock)),
                     own_cpu_s=lambda: float(next(own)))
    with spare.work():   # the first span: nothing measured before it
        pass
    return spare


def test_the_localiser_segments_its_views_in_one_thread_on_a_busy_host(ros):
    from tlessbot_ros.nodes.localiser import LocaliserNode
    from tlessbot_ros.tools.commands.bench.nodes import bag_frames
    from tlessbot_ros.tools.support.defaults import DEFAULT_BAG

    frames = bag_frames(str(DEFAULT_BAG))[:2]
    node = LocaliserNode()
    assert node.get_parameter('parallel.min_spare_cores').value == 0.5
    assert node.wait_ready()
    labels = {}
    for idle, expected in ((0.1, 0), (1.5, 1)):
        node.spare_cpu = _host(idle)
        node._label_publishers = {c: _Captured() for c in node.cameras}
        for frame in frames:
            node.process({c: dict(m) for c, m in frame.items()})
            assert node._stats['views_in_parallel'] == expected
        labels[idle] = [bytes(m) for c in node.cameras
                        for m in node._label_publishers[c].messages]
    assert labels[0.1] == labels[1.5]   # the same labels either way
    node.destroy_node()
