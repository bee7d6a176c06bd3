"""A stage node and the clock of its input stamps: input age only for stamps of its own clock,
and stamps that jump (a looped bag, a clock step) restart the synchronisation."""
from __future__ import annotations

import numpy as np
import pytest

pytestmark = pytest.mark.ros

S = 1_000_000_000
PERIOD = S // 2
BAG_START = 1_700_000_000 * S


@pytest.fixture
def ros():
    import rclpy

    rclpy.init()
    yield
    rclpy.try_shutdown()


class _Probe:
    """A StageNode that records what it is handed, fed raw CDR through its real inputs."""

    def __init__(self, jump_confirmations: int | None = None):
        from tlessbot_ros.nodes.stage import StageNode

        class Probe(StageNode):
            def __init__(self, **kwargs):
                super().__init__('clock_probe', **kwargs)
                self.seen = []

            def process(self, views):
                self.seen.append({c: msgs['color'].header.stamp.sec for c, msgs in views.items()})

        from rclpy.parameter import Parameter

        overrides = [Parameter('sync.worker_thread', value=False)]
        if jump_confirmations is not None:
            overrides.append(Parameter('sync.jump_confirmations', value=jump_confirmations))
        self.node = Probe(parameter_overrides=overrides)
        self.node.setup_inputs({'color': ('sensor_msgs/msg/Image', lambda c: f'/{c}/color'),
                                'depth': ('sensor_msgs/msg/Image', lambda c: f'/{c}/depth')})
        self.handlers = {(camera, key): self.node._inputs._handler(camera, key, _image_class())
                         for camera in ('top', 'side') for key in ('color', 'depth')}

    def frame(self, stamp_ns: int, cameras=('top', 'side')) -> None:
        from tlessbot_ros.conversions.image_cdr import image_to_cdr

        data = image_to_cdr(np.zeros((2, 2), np.uint16), '16UC1', stamp_ns=stamp_ns)
        for camera in cameras:
            for key in ('color', 'depth'):
                self.handlers[camera, key](data)


def _image_class():
    from tlessbot_ros.nodes.common import message_class

    return message_class('sensor_msgs/msg/Image')


def test_a_bag_looped_without_restamp_is_paired_again_after_each_jump(ros):
    probe = _Probe()
    node = probe.node
    for _ in range(3):                      # three passes over a bag of 4 frames
        for i in range(4):
            probe.frame(BAG_START + i * PERIOD)
    assert len(node.seen) == 12 and node.failures == 0
    assert [s['side'] for s in node.seen] == [1_700_000_000 + i // 2 for i in range(4)] * 3
    values = node._clock_values()
    assert values['time_jumps'] == 2 and values['last_time_jump_s'] == '-1.500'
    # the bag's stamps are years old: another clock, reported as an offset, not an age
    assert values['other_clock_frames'] == 12 and float(values['stamp_offset_s']) > 86_400
    assert not node._input_ages_ms
    node.destroy_node()


def test_stragglers_of_the_old_timeline_are_dropped_and_the_ages_start_again(ros):
    probe = _Probe(jump_confirmations=0)   # the jump at once (what is held: test_sync.py)
    node = probe.node
    now = node.get_clock().now().nanoseconds
    for i in range(3):                                 # a live camera, 3-4 s late
        probe.frame(now - 4 * S + i * PERIOD)
    ages = list(node._input_ages_ms)
    assert len(ages) == 3 and all(2_900 < age < 4_900 for age in ages)
    probe.frame(now - 4 * S + 3 * PERIOD, cameras=('top',))   # side's half is still coming
    probe.frame(now - 7 * S // 2, cameras=('top',))   # the clock stepped back 1 s
    assert node._inputs.jumps.count == 1 and not node._input_ages_ms   # ages start again
    probe.frame(now - 4 * S + 3 * PERIOD, cameras=('side',))  # the late half: dropped
    assert len(node.seen) == 3 and node._inputs.stale == 2
    probe.frame(now - 7 * S // 2, cameras=('side',))
    assert len(node.seen) == 4 and len(node._input_ages_ms) == 1
    probe.frame(now - 3 * S)
    assert len(node.seen) == 5 and node._inputs.jumps.count == 1
    assert len(node._input_ages_ms) == 2 and node.other_clock_frames == 0
    values = node._clock_values()
    assert values['time_jumps'] == 1 and values['last_time_jump_s'] == '-1.000'
    node.destroy_node()
