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


def test_free_running_cameras_with_a_phase_offset_still_pair_at_once():
    sync = StampSynchroniser(['top', 'side'], slop_ns=50 * MS, queue_size=4)
    emitted = []
    for i in range(6):
        for stream, offset in (('side', 0), ('top', 14)):
            result = sync.add(stream, (i * 33 + offset) * MS, f'{stream}{i}')
            if result:
                emitted.append((result['side'], result['top']))
    assert emitted == [(f'side{i}', f'top{i}') for i in range(6)]


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
