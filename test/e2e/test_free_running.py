"""The graph free-running, as a cell runs it: frames at the bag's own rate after "ready", a
rig given through a YAML that differs from config/cell.yaml, compared with the lock-step
replay of the same bag (each frame sent once the previous one is answered)."""
from __future__ import annotations

import shutil

import pytest

from tlessbot_ros.data import DEFAULT_CLASSIFIER, DEFAULT_MODELS_INFO, DEFAULT_TEMPLATES
from tlessbot_ros.tools.commands.demo import run_demo
from tlessbot_ros.tools.support.models_info import load_symmetries

pytestmark = [pytest.mark.ros, pytest.mark.rosbag, pytest.mark.slow]

FPS = 2.0
FRAMES = 6


def _run(bag, config, **kwargs) -> dict:
    return run_demo(str(bag), config=config, classifier=str(DEFAULT_CLASSIFIER),
                    templates=str(DEFAULT_TEMPLATES),
                    symmetries=load_symmetries(DEFAULT_MODELS_INFO), echo=False, **kwargs)


@pytest.fixture(scope='module')
def lockstep(moved_rig_bag) -> dict:
    bag, config = moved_rig_bag
    return _run(bag, config)


def _rate_this_host_keeps_up_with(lockstep: dict) -> float:
    """The replay rate factor: the bag's own rate (1.0), or slower where this host, now, needs
    more than a frame period for a frame. In lock-step each frame is published once the
    previous one is answered, so the slowest interval between publications is the longest
    trip through the graph; free-running with two frames in flight then keeps up. (A busy CI
    machine took over 0.5 s a frame and lost frames at 2 frames/s by design: dropped at the
    entrance. At the recorded rate on a quiet machine: docs/bench/free-running.md.) Half that
    rate, since the host's load can change between the two runs (once, with other work
    starting beside the test, one frame of six was dropped at the full one)."""
    return min(1.0, 0.5 * (1.0 / FPS) / max(lockstep['frame_intervals_s']))


def test_at_the_recorded_rate_every_frame_is_answered_as_in_lock_step(moved_rig_bag, lockstep):
    bag, config = moved_rig_bag
    rate = _rate_this_host_keeps_up_with(lockstep)
    free = _run(bag, config, lockstep=False, rate=rate)
    assert lockstep['frames_answered'] == FRAMES
    # a lost frame: which one, and where (each stage's drop counters), at what rate
    assert free['frames_answered'] == FRAMES, (
        free['per_frame'], free['node_diagnostics'], rate, lockstep['frame_intervals_s'],
        free['frame_intervals_s'])
    assert free['recall_5cm5deg'] >= 0.95 * lockstep['recall_5cm5deg'], (free, lockstep)
    assert free['duplicates'] == 0 and lockstep['duplicates'] == 0
    assert free['false_positives'] <= lockstep['false_positives'] + 1


def test_faster_than_the_graph_frames_are_dropped_whole(moved_rig_bag, lockstep):
    """At 10 frames/s (5 x the bag's rate) with no admission cap some frames are skipped; each
    frame answered is answered whole and right, as in lock-step, and the skipped ones are
    counted (dropped, or estimated unread at the entrance), not queued."""
    bag, config = moved_rig_bag
    free = _run(bag, config, lockstep=False, rate=10.0 / FPS)
    reference = {f['stamp_ns']: f for f in lockstep['per_frame']}
    answered = [f for f in free['per_frame'] if f['poses']]
    assert answered, free['per_frame']
    for frame in answered:
        expected = reference[frame['stamp_ns']]
        assert frame['duplicates'] == 0, frame
        assert frame['poses'] >= expected['poses'] - 1, (frame, expected)
        assert frame['correct'] >= expected['correct'] - 1, (frame, expected)
    skipped = FRAMES - len(answered)
    if skipped:   # dropped, or left unread in DDS while the entrance was full
        dropped = sum(int(values.get('dropped', 0)) + int(values.get('unread_frames_est', 0))
                      for values in free['node_diagnostics'].values())
        assert dropped >= 1, free['node_diagnostics']


def test_a_frame_missing_its_side_image_is_never_mixed_with_the_next(moved_rig_bag, lockstep,
                                                                     tmp_path):
    from rosbags.rosbag2 import Reader, StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    typestore = get_typestore(Stores.ROS2_JAZZY)

    bag, config = moved_rig_bag
    reference = {f['stamp_ns']: f for f in lockstep['per_frame']}
    stamps = sorted(reference)
    victim = stamps[2]
    cut = tmp_path / 'cut'
    with Reader(bag) as reader, \
            Writer(cut, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        connections = {c.id: writer.add_connection(c.topic, c.msgtype, typestore=typestore)
                       for c in reader.connections}
        for connection, timestamp, raw in reader.messages():
            if connection.topic == '/side/color/image_raw' and timestamp == victim:
                continue
            writer.write(connections[connection.id], timestamp, raw)
    free = _run(cut, config, lockstep=False)
    frames = {f['stamp_ns']: f for f in free['per_frame']}
    hit = frames[victim]
    assert hit['false_positives'] <= reference[victim]['false_positives'], hit
    assert hit['duplicates'] == 0
    # The frames after it: each one answered is answered as in lock-step (nothing of the cut
    # frame mixed in), and the graph answers again. Which of them it answers depends on the
    # host's speed, free-running: a frame that comes while the graph is full is dropped whole
    # at the entrance, by design (docs/bench/backpressure.md).
    answered = [stamp for stamp in stamps[3:] if frames.get(stamp, {}).get('poses')]
    assert answered, [frames.get(stamp) for stamp in stamps[3:]]
    for stamp in answered:
        after, expected = frames[stamp], reference[stamp]
        assert after['poses'] == expected['poses'], (after, expected)
        assert after['duplicates'] == 0 and \
            after['false_positives'] <= expected['false_positives'], (after, expected)
    shutil.rmtree(cut, ignore_errors=True)
