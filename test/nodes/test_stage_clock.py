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

    def __init__(self, jump_confirmations: int | None = None, *, after_localiser=False,
                 input_source: str | None = None):
        from tlessbot_ros.nodes.stage import StageNode

        class Probe(StageNode):
            def __init__(self, **kwargs):
                super().__init__('clock_probe', after_localiser=after_localiser, **kwargs)
                self.seen = []

            def process(self, views):
                self.seen.append({c: msgs['color'].header.stamp.sec for c, msgs in views.items()})

        from rclpy.parameter import Parameter

        overrides = [Parameter('sync.worker_thread', value=False)]
        if jump_confirmations is not None:
            overrides.append(Parameter('sync.jump_confirmations', value=jump_confirmations))
        if input_source is not None:
            overrides.append(Parameter('input_source', value=input_source))
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


@pytest.mark.parametrize('after_localiser, input_source, confirmations', [
    (False, None, 4),          # the localiser: camera topics, where strays may come
    (True, None, 0),           # behind its relay (the default): jumps come confirmed
    (True, 'cameras', 4)])     # a later stage on the camera topics confirms them itself
def test_jumps_are_confirmed_where_the_camera_topics_are_read(ros, after_localiser, input_source,
                                                               confirmations):
    node = _Probe(after_localiser=after_localiser, input_source=input_source).node
    assert node.sync_params.jump_confirmations == confirmations
    assert node.get_parameter('sync.jump_confirmations').value == confirmations
    assert node.has_parameter('input_source') == after_localiser
    node.destroy_node()


def test_a_stage_behind_the_relay_follows_a_loop_that_brings_one_frame_per_pass(ros):
    # What the localiser admits of a short bag looped without --restamp can be one frame a
    # pass: a stage that waited for more frames of the new timeline to confirm each step back
    # would hold them for ever (the last one here).
    admitted = [3, 1, 2, 0]   # frame of the bag admitted in each pass
    behind = _Probe(after_localiser=True)
    on_cameras = _Probe(after_localiser=True, input_source='cameras')
    for probe in (behind, on_cameras):
        for frame in admitted:
            probe.frame(BAG_START + frame * PERIOD)
    assert [s['top'] for s in behind.node.seen] == [BAG_START // S + f // 2 for f in admitted]
    assert behind.node._inputs.jumps.count == 2
    assert len(on_cameras.node.seen) == 3   # 0 waits for a confirmation that never comes
    for probe in (behind, on_cameras):
        probe.node.destroy_node()


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
