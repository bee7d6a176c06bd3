import numpy as np
import pytest

from tlessbot_ros.core.common import StampSynchroniser

MS = 1_000_000


def test_sets_form_within_slop_in_any_arrival_order():
    sync = StampSynchroniser(['color', 'depth', 'info'], slop_ns=5 * MS, queue_size=5)
    assert sync.add('depth', 100 * MS, 'd1') is None
    assert sync.add('info', 101 * MS, 'i1') is None
    assert sync.add('color', 99 * MS, 'c1') == {'color': 'c1', 'depth': 'd1', 'info': 'i1'}
    assert sync.pending() == {'color': 0, 'depth': 0, 'info': 0}
    assert (sync.emitted, sync.dropped) == (1, 0)


def test_stale_items_are_dropped_not_kept():
    sync = StampSynchroniser(['a', 'b'], slop_ns=1 * MS, queue_size=3)
    for i in range(10):  # 'a' frames whose partners never come
        sync.add('a', i * 33 * MS, i)
    assert sync.pending()['a'] == 3 and sync.dropped == 7
    # A partner for the newest 'a' emits it and discards the older 'a' items still queued.
    assert sync.add('b', 9 * 33 * MS, 'b9') == {'a': 9, 'b': 'b9'}
    assert sync.pending() == {'a': 0, 'b': 0}
    assert sync.dropped == 9


def test_outside_slop_does_not_pair():
    sync = StampSynchroniser(['top', 'side'], slop_ns=50 * MS, queue_size=2)
    assert sync.add('top', 0, 't0') is None
    assert sync.add('side', 51 * MS, 's0') is None
    assert sync.add('top', 60 * MS, 't1') == {'top': 't1', 'side': 's0'}


def test_bad_arguments_raise():
    with pytest.raises(ValueError):
        StampSynchroniser(['a', 'a'], slop_ns=0, queue_size=1)
    with pytest.raises(KeyError, match='unknown stream'):
        StampSynchroniser(['a'], slop_ns=0, queue_size=1).add('b', 0, None)


def test_a_late_frame_is_not_paired_with_the_previous_frame_of_the_other_camera():
    """max_age (50 ms) is wider than the frame period (33 ms): when the side set of a frame
    completes before the top set of the same frame, the older top frame must not be taken."""
    sync = StampSynchroniser(['top', 'side'], slop_ns=50 * MS, queue_size=4)
    for i in range(3):
        assert sync.add('top', i * 33 * MS, f't{i}') is None
        assert sync.add('side', i * 33 * MS, f's{i}') == {'top': f't{i}', 'side': f's{i}'}
    assert sync.add('top', 99 * MS, 't3') is None             # s3 is lost: t3 stays queued
    assert sync.add('side', 132 * MS, 's4') is None           # t4 is late; t3 is not taken
    assert sync.add('top', 132 * MS, 't4') == {'top': 't4', 'side': 's4'}
    assert sync.dropped == 1                                  # t3


def test_a_late_frame_waits_for_its_partner_even_when_most_steps_are_skipped_frames():
    """A reader that leaves frames unread (the paused entrance) sees steps of several periods
    as often as single ones; the period is still one step, so top 633 waits for side 633
    instead of taking side 600, the frame before it."""
    sync = StampSynchroniser(['top', 'side'], slop_ns=50 * MS, queue_size=2)
    for stamp in (0, 33, 200, 367, 400, 567):   # steps 33, 167, 167, 33, 167 ms
        sync.add('top', stamp * MS, f't{stamp}')
        assert sync.add('side', stamp * MS, f's{stamp}') == {'top': f't{stamp}',
                                                             'side': f's{stamp}'}
    assert sync.add('side', 600 * MS, 's600') is None   # its top set never completed
    assert sync.add('top', 633 * MS, 't633') is None    # side 633 is due: not side 600
    assert sync.add('side', 633 * MS, 's633') == {'top': 't633', 'side': 's633'}


def test_the_period_of_a_stream_is_its_lower_quartile_step():
    from tlessbot_ros.core.common import stream_period_ns

    assert stream_period_ns([5]) is None and stream_period_ns([5, 5]) is None
    assert stream_period_ns([0, 33, 200, 367, 400, 567, 600]) == 33   # median would be 167
    assert stream_period_ns([0, 33, 66, 67, 100, 133, 166, 200, 233]) == 33   # one stray


def test_free_running_cameras_with_a_phase_offset_still_pair_at_once():
    sync = StampSynchroniser(['top', 'side'], slop_ns=50 * MS, queue_size=4)
    emitted = []
    for i in range(6):
        for stream, offset in (('side', 0), ('top', 14)):
            result = sync.add(stream, (i * 33 + offset) * MS, f'{stream}{i}')
            if result:
                emitted.append((result['side'], result['top']))
    assert emitted == [(f'side{i}', f'top{i}') for i in range(6)]


S = 1_000_000_000


def _jumps(**kwargs):
    from tlessbot_ros.core.common import StampJumps

    return StampJumps(back_ns=kwargs.pop('back_ns', S // 10), forward_ns=10 * S,
                      confirmations=kwargs.pop('confirmations', 2), **kwargs)


def _gated(sync, jumps):
    """``add(stream, stamp, item)`` through a TimelineGate in front of ``sync``, as the nodes'
    inputs pair their messages."""
    from tlessbot_ros.core.common import TimelineGate

    gate = TimelineGate(jumps, [sync])

    def add(stream, stamp, item):
        """The sets this item completes (several when it confirms a jump and held items are
        released), in order."""
        _, released = gate.admit(stream, stamp, item)
        emitted = [sync.add(name, at, held) for name, at, held in released]
        return [result for result in emitted if result]
    return add


def _looped(add, frames: int, passes: int, streams=('color', 'depth')):
    """Two streams of a bag of ``frames`` frames (0.5 s apart) replayed ``passes`` times."""
    emitted = []
    for _ in range(passes):
        for i in range(frames):
            for stream in streams:
                emitted += add(stream, 100 * S + i * S // 2, f'{stream}{i}')
    return emitted


def test_a_looped_bag_is_paired_again_on_every_pass_and_each_loop_counted():
    jumps = _jumps()
    sync = StampSynchroniser(['color', 'depth'], slop_ns=5 * MS, queue_size=5)
    emitted = _looped(_gated(sync, jumps), frames=4, passes=3)
    # A pass's first items are held until two more confirm the jump, then paired: every pass
    # gives every frame.
    first = [{'color': f'color{i}', 'depth': f'depth{i}'} for i in range(4)]
    assert emitted == first * 3
    assert jumps.count == 2 and jumps.last_jump_ns == -3 * S // 2
    assert sync.pending() == {'color': 0, 'depth': 0}


def test_without_jump_detection_a_loop_leaves_stale_items_behind():
    """Why the synchroniser needs to notice: the old pass's items block the queue front."""
    sync = StampSynchroniser(['color', 'depth'], slop_ns=5 * MS, queue_size=5)
    sync.add('color', 100 * S + 3 * S // 2, 'old')   # the last frame's depth never came
    sync.add('color', 100 * S, 'c0')                  # the loop starts again
    assert sync.add('depth', 100 * S, 'd0') == {'color': 'c0', 'depth': 'd0'}
    assert sync.pending()['color'] == 2               # 'old' and the emitted 'c0' stay


def test_a_jump_empties_the_queues_and_the_old_timelines_stragglers_are_dropped():
    """The pose stage's classes lag behind the camera: after the camera's stamps jump back,
    classes of the old pass still arrive; they must not pair, nor count as another jump."""
    jumps = _jumps()
    sync = StampSynchroniser(['depth', 'classes'], slop_ns=5 * MS, queue_size=5)
    add = _gated(sync, jumps)
    old = [100 * S + i * S // 2 for i in range(5)]
    for stamp in old[:3]:
        add('depth', stamp, 'old depth')
        assert add('classes', stamp, 'old classes')
    add('depth', old[3], 'old depth 3')               # its classes are on their way
    assert add('depth', old[0], 'new depth 0') == []          # held: no jump yet
    assert add('depth', old[1], 'new depth 1') == []
    assert jumps.count == 0
    assert add('depth', old[2], 'new depth 2') == []          # the second confirms it
    assert jumps.count == 1 and sync.pending() == {'depth': 3, 'classes': 0}
    assert add('classes', old[4], 'old classes 4') == []                    # a straggler
    assert sync.pending() == {'depth': 3, 'classes': 0}
    assert add('classes', old[0], 'new classes 0') == [{'depth': 'new depth 0',
                                                         'classes': 'new classes 0'}]
    assert add('classes', old[2], 'new classes 2') == [{'depth': 'new depth 2',
                                                         'classes': 'new classes 2'}]
    assert jumps.count == 1                            # one jump, seen on both streams


def test_stamps_leaping_forward_are_a_jump_too_and_small_steps_are_not():
    jumps = _jumps()
    assert jumps.check('a', 100 * S) == 'in order'
    assert jumps.check('a', 100 * S - S // 20) == 'in order'      # 50 ms back: a correction
    assert jumps.check('a', 130 * S) == 'in order'                # a leap goes through ...
    assert jumps.check('a', 130 * S + S // 30) == 'in order'
    assert jumps.check('a', 130 * S + S // 15) == 'jump'          # ... and is confirmed
    assert jumps.last_jump_ns == 30 * S + S // 20
    assert jumps.check('b', 100 * S) == 'in order'                # first item of b: no history
    assert jumps.check('a', 131 * S) == 'in order'


def test_a_stray_item_off_the_timeline_is_dropped_and_no_jump():
    """Garbage with absurd stamps between good messages must not reset the pairing."""
    jumps = _jumps()
    for i in range(3):
        assert jumps.check('a', 100 * S + i * S // 30) == 'in order'
    for strays in ((5 * S,), (50 * S, 51 * S), (90 * S, 91 * S)):
        for stray in strays:   # even two in line with each other are not yet a jump
            assert jumps.check('a', stray) == 'stale'
        assert jumps.check('a', 100 * S + 3 * S // 30) == 'in order'
    assert jumps.check('a', 10**9 * S) == 'in order'   # a stray far ahead goes through, but
    assert jumps.check('a', 100 * S + 4 * S // 30) == 'in order'   # does not move the timeline
    assert jumps.count == 0 and jumps.outliers == 5


def test_without_confirmations_every_step_back_is_a_jump_at_once():
    jumps = _jumps(confirmations=0)
    assert jumps.check('a', 100 * S) == 'in order'
    assert jumps.check('a', 50 * S) == 'jump' and jumps.last_jump_ns == -50 * S


def test_a_stream_whose_clock_did_not_jump_joins_after_the_stale_limit():
    jumps = _jumps(stale_limit=3)
    for i in range(3):
        jumps.check('top', 100 * S + i * S)
        jumps.check('side', 100 * S + i * S)
    assert jumps.check('top', 50 * S) == 'stale'                  # only top's clock stepped
    assert jumps.check('top', 51 * S) == 'stale'
    assert jumps.check('top', 52 * S) == 'jump'
    verdicts = [jumps.check('side', 103 * S + i * S) for i in range(5)]
    assert verdicts == ['stale'] * 3 + ['in order'] * 2
    assert jumps.count == 1


def test_jump_thresholds_are_validated():
    from tlessbot_ros.core.common import StampJumps, SyncParams

    with pytest.raises(ValueError, match='jump_back_s'):
        SyncParams(jump_back_s=0.0)
    with pytest.raises(ValueError):
        StampJumps(back_ns=0, forward_ns=S)


def test_the_executor_is_one_rclpy_has():
    from tlessbot_ros.core.common import SyncParams

    assert SyncParams().executor == 'events'
    assert SyncParams(executor='single_threaded').executor == 'single_threaded'
    with pytest.raises(ValueError, match="executor must be one of.*'multi'"):
        SyncParams(executor='multi')


def test_full_queue_drops_an_item_that_can_never_pair_first():
    """A flood on one stream at stamps nobody else has pushes out the flood, not the item
    that waits for its partner (a later stage's input waiting for its upstream result)."""
    sync = StampSynchroniser(['depth', 'info', 'classes'], slop_ns=10, queue_size=3)
    assert sync.add('depth', 1000, 'good depth') is None
    assert sync.add('info', 1000, 'good info') is None
    for k in range(10):
        assert sync.add('depth', 5_000 + 100 * k, f'garbage {k}') is None
    assert sync.add('classes', 1000, 'classes') == {
        'depth': 'good depth', 'info': 'good info', 'classes': 'classes'}


def test_full_queue_of_pairable_items_drops_the_oldest():
    sync = StampSynchroniser(['a', 'b', 'c'], slop_ns=10, queue_size=2)
    for stamp in (100, 200, 300):
        sync.add('a', stamp, f'a{stamp}')
        sync.add('b', stamp, f'b{stamp}')
    assert sync.dropped == 2
    assert sync.add('c', 100, 'c') is None   # a100 and b100 are gone
    assert sync.add('c', 300, 'c')['a'] == 'a300'


def test_strays_held_as_a_candidate_are_dropped_when_the_old_timeline_goes_on():
    from tlessbot_ros.core.common import TimelineGate

    jumps = _jumps()
    sync = StampSynchroniser(['color', 'depth'], slop_ns=5 * MS, queue_size=5)
    gate = TimelineGate(jumps, [sync])

    def add(stream, stamp, item):
        _, released = gate.admit(stream, stamp, item)
        return [r for r in (sync.add(*entry) for entry in released) if r]

    assert add('color', 100 * S, 'c0') == []
    assert add('color', 5 * S, 'stray 1') == [] and add('color', 5 * S + MS, 'stray 2') == []
    assert len(gate._held['color']) == 2   # noqa: SLF001  (held as a candidate timeline)
    assert add('depth', 100 * S, 'd0') == [{'color': 'c0', 'depth': 'd0'}]   # nothing emptied
    assert add('color', 100 * S + S // 30, 'c1') == []       # the old timeline goes on
    assert jumps.count == 0 and jumps.outliers == 2
    assert gate._held == {} and gate.stale == 2   # noqa: SLF001  (the strays are dropped)


def test_the_gate_holds_at_most_confirmations_items_per_stream_under_garbage():
    from tlessbot_ros.core.common import TimelineGate

    rng = np.random.default_rng(3)
    jumps = _jumps(confirmations=2)
    sync = StampSynchroniser(['color', 'depth'], slop_ns=5 * MS, queue_size=5)
    gate = TimelineGate(jumps, [sync])
    emitted = 0
    for i in range(200):
        good = 100 * S + i * S // 30
        for stream in ('color', 'depth'):
            _, released = gate.admit(stream, good, (stream, i))
            emitted += sum(1 for name, at, item in released if sync.add(name, at, item))
            for _ in range(3):   # garbage: absurd stamps, rarely two in line
                gate.admit(stream, int(rng.integers(1, 10**6)) * S, 'garbage')
                assert all(len(items) <= 2 for items in gate._held.values())  # noqa: SLF001
    assert emitted == 200 and jumps.count == 0


def test_a_leap_forward_keeps_the_items_that_went_through_before_it_was_confirmed():
    from tlessbot_ros.core.common import TimelineGate

    jumps = _jumps()
    sync = StampSynchroniser(['color', 'depth'], slop_ns=5 * MS, queue_size=5)
    gate = TimelineGate(jumps, [sync])
    emitted = []

    def add(stream, stamp, item):
        verdict, released = gate.admit(stream, stamp, item)
        emitted.extend(r for r in (sync.add(*entry) for entry in released) if r)
        return verdict

    add('color', 100 * S, 'old c')   # its depth never comes
    verdicts = [add(stream, 200 * S + i * S // 30, f'{stream}{i}')
                for i in range(3) for stream in ('color', 'depth')]
    assert 'jump' in verdicts and jumps.count == 1 and jumps.last_jump_ns == 100 * S
    assert emitted == [{'color': f'color{i}', 'depth': f'depth{i}'} for i in range(3)]
    assert sync.pending() == {'color': 0, 'depth': 0}   # 'old c' is gone


def test_a_looped_bag_through_two_cameras_loses_no_frame_at_its_jumps():
    """A looped bag through a node's inputs (three topics per camera, two cameras): a pass's
    first frame is held until the second, seen alike on two topics, confirms the jump; then
    it is paired, and every frame comes in order."""
    from tlessbot_ros.core.common import TimelineGate

    jumps = _jumps(confirmations=2)
    per_camera = {camera: StampSynchroniser(['color', 'depth', 'info'], slop_ns=10 * MS,
                                            queue_size=30) for camera in ('top', 'side')}
    across = StampSynchroniser(['top', 'side'], slop_ns=50 * MS, queue_size=2)
    gate = TimelineGate(jumps, [*per_camera.values(), across])
    answered, jumped_at = [], []
    for loop in range(3):
        for frame in range(4):
            for camera in ('top', 'side'):
                for key in ('color', 'depth', 'info'):
                    verdict, released = gate.admit((camera, key), 100 * S + frame * S // 2,
                                                   frame)
                    if verdict == 'jump':
                        jumped_at.append((loop, frame))
                    for (cam, k), stamp, item in released:
                        complete = per_camera[cam].add(k, stamp, item)
                        views = complete and across.add(cam, stamp, complete)
                        if views:
                            answered.append((loop, views['top']['color']))
    assert jumped_at == [(1, 1), (2, 1)]
    assert [frame for _, frame in answered] == [0, 1, 2, 3] * 3


def test_a_stray_frame_on_every_topic_is_not_confirmed_by_strays_that_differ_per_topic():
    """A whole frame with a stray stamp (one message corrupted, say), then on each topic a
    stray of its own in line with it: no two topics agree on two stamps, so no jump."""
    jumps = _jumps()
    for topic in ('color', 'depth', 'info'):
        assert jumps.check(topic, 100 * S) == 'in order'
    for topic in ('color', 'depth', 'info'):
        assert jumps.check(topic, 90 * S) == 'stale'
    for k, topic in enumerate(('color', 'depth', 'info')):
        assert jumps.check(topic, 91 * S + k * MS) == 'stale'
    assert jumps.count == 0
    assert jumps.check('color', 100 * S + S // 30) == 'in order'


def test_skipped_frames_are_counted_from_the_gaps_once_the_period_is_known():
    from tlessbot_ros.core.common import SkippedFrames

    skipped = SkippedFrames(window=4)
    skipped.add(0)
    skipped.add(100)             # a gap, but no period is known yet
    assert skipped.count == 0
    skipped.add(133)             # the period is 33: the first step skipped two frames
    assert skipped.count == 2
    for stamp in (166, 299, 332):   # one more gap of four periods: three more
        skipped.add(stamp)
    assert skipped.count == 5    # the first steps left the window with their count
    skipped.add(10)              # a new timeline: counted so far is kept
    skipped.add(43)
    assert skipped.count == 5



def test_items_read_after_a_pause_keep_each_streams_order_and_interleave_by_timeline():
    jumps = _jumps()
    for stream in ('color', 'depth'):
        assert jumps.check(stream, 100 * S) == 'in order'
    color = [(101 * S, 'c1'), (9 * S, 'c-stray'), (102 * S, 'c2'), (10**9 * S, 'c-ahead'),
             (103 * S, 'c3')]
    depth = [(101 * S, 'd1'), (102 * S, 'd2'), (0, 'd-zero'), (103 * S, 'd3')]
    order = jumps.reading_order({'color': color, 'empty': [], 'depth': depth})
    items = [item for _, _, item in order]
    assert sorted(items) == sorted(item for _, item in color + depth)   # each once
    assert [(stream, stamp) for stream, stamp, _ in order if stream == 'color'] == \
        [('color', stamp) for stamp, _ in color]   # each stream's own order, as it came
    # a stray comes right after the item before it in its stream; by timeline across streams
    assert items == ['c1', 'c-stray', 'd1', 'c2', 'c-ahead', 'd2', 'd-zero', 'c3', 'd3']
    assert jumps.count == 0 and jumps.outliers == 0   # reading the order changes nothing


def test_strays_read_together_after_a_pause_stay_strays_and_every_good_frame_pairs():
    """A paused entrance reads every topic's waiting messages at once (nodes.inputs). Garbage
    with a few kinds of stamps taking turns between good messages: read in the order they
    came, no two strays of a kind are in line, so there is no jump and every good frame pairs.
    Sorted by their own stamps, the strays of each kind come in a row and confirm a jump to
    their timeline."""
    from tlessbot_ros.core.common import SyncParams, TimelineGate

    rng = np.random.default_rng(5)
    kinds = (lambda: 1 * S + int(rng.integers(0, 5 * S)),        # the 1970s
             lambda: 10**8 * S + int(rng.integers(0, 5 * S)),    # years ahead
             lambda: 90 * S - int(rng.integers(0, 5 * S)))       # seconds before the frames
    waiting = {}
    for key in ('color', 'depth', 'info'):
        waiting[key] = []
        for frame in range(1, 7):
            waiting[key].append((100 * S + frame * S // 2, f'good{frame}'))
            waiting[key] += [(kind(), 'stray') for kind in kinds for _ in range(2)]

    def read(order_of):
        jumps = _jumps(confirmations=4)
        sync = StampSynchroniser(list(waiting), slop_ns=5 * MS,
                                 queue_size=SyncParams().queue_size)
        gate = TimelineGate(jumps, [sync])
        for key in waiting:   # the frame read before the pause
            gate.admit(key, 100 * S, 'good0')
            sync.add(key, 100 * S, 'good0')
        frames = []
        for key, stamp, item in order_of(jumps):
            for name, at, held in gate.admit(key, stamp, item)[1]:
                if (complete := sync.add(name, at, held)) and complete['color'] != 'stray':
                    frames.append(complete['color'])
        return jumps.count, frames

    assert read(lambda jumps: jumps.reading_order(waiting)) == \
        (0, [f'good{i}' for i in range(1, 7)])
    by_stamp = sorted(((key, stamp, item) for key, items in waiting.items()
                       for stamp, item in items), key=lambda entry: entry[1])
    assert read(lambda _: by_stamp)[0] > 0
