"""Instance names that hold: seeded resting parts with pose noise, moved, added and removed
parts, time jumps and a symmetric part."""
import numpy as np
import pytest

from tlessbot_ros.core.common.geometry import make_transform, rotation_about_axis
from tlessbot_ros.core.track import InstanceTracker, Observation, TrackParams, nearest_equivalent

SECOND = 1_000_000_000


def pose(x, y, yaw_deg=0.0):
    return make_transform(rotation_about_axis(np.array([0, 0, 1.0]), np.radians(yaw_deg)),
                          np.array([x, y, 0.02]))


def noisy(T, rng, sigma_m=0.002, sigma_deg=2.0):
    axis = rng.normal(size=3)
    R = rotation_about_axis(axis / np.linalg.norm(axis), np.radians(rng.normal(0, sigma_deg)))
    return make_transform(R @ T[:3, :3], T[:3, 3] + rng.normal(0, sigma_m, 3))


def names_by_position(tracked):
    return {(round(t.T_world_part[0, 3], 1), round(t.T_world_part[1, 3], 1)): t.instance
            for t in tracked}


def test_resting_parts_of_one_class_never_swap():
    rng = np.random.default_rng(0)
    scene = [('obj_05', pose(0.0, 0.0)), ('obj_05', pose(0.1, 0.0)), ('obj_07', pose(0.0, 0.1))]
    tracker = InstanceTracker()
    first = None
    for frame in range(30):
        order = rng.permutation(len(scene))   # the stage reports parts in any order
        obs = [Observation(scene[k][0], noisy(scene[k][1], rng)) for k in order]
        named = names_by_position(tracker.update(frame * SECOND // 15, obs))
        first = first or named
        assert named == first
    assert sorted(first.values()) == ['obj_05_1', 'obj_05_2', 'obj_07_1']


def test_moved_added_and_removed_parts():
    tracker = InstanceTracker(TrackParams(ttl_s=1.0))
    a, b, c = pose(0.0, 0.0), pose(0.1, 0.0), pose(0.0, 0.1)
    tracked = tracker.update(0, [Observation('obj_05', a), Observation('obj_05', b),
                                 Observation('obj_07', c)])
    assert [t.instance for t in tracked] == ['obj_05_1', 'obj_05_2', 'obj_07_1']
    assert all(t.new for t in tracked)
    # obj_05_2 moved 8 cm, obj_07 removed, an obj_09 added
    moved = pose(0.1, 0.08)
    tracked = tracker.update(SECOND // 2, [Observation('obj_05', a), Observation('obj_05', moved),
                                           Observation('obj_09', pose(-0.1, 0.0))])
    assert [(t.instance, t.new) for t in tracked] == [
        ('obj_05_1', False), ('obj_05_3', True), ('obj_09_1', True)]
    # within the time to live the removed and the moved-away instances are still known ...
    assert {'obj_07_1', 'obj_05_2'} <= set(tracker.instances)
    for t_ns in range(SECOND // 2, 2 * SECOND, SECOND // 10):
        tracker.update(t_ns, [Observation('obj_05', a), Observation('obj_05', moved)])
    # ... after it, gone; the names of the parts that stayed hold
    assert set(tracker.instances) == {'obj_05_1', 'obj_05_3'}


def test_a_part_missed_for_a_frame_keeps_its_name():
    tracker = InstanceTracker()
    tracker.update(0, [Observation('obj_05', pose(0, 0))])
    tracker.update(SECOND // 10, [])
    assert tracker.update(SECOND // 5, [Observation('obj_05', pose(0.005, 0))])[0].instance == \
        'obj_05_1'


def test_a_part_turned_beyond_the_gate_is_new():
    tracker = InstanceTracker()
    tracker.update(0, [Observation('obj_05', pose(0, 0))])
    turned = tracker.update(SECOND // 10, [Observation('obj_05', pose(0, 0, yaw_deg=90))])
    assert turned[0].instance == 'obj_05_2'


def test_time_jump_resets_names():
    tracker = InstanceTracker()
    tracker.update(10 * SECOND, [Observation('obj_05', pose(0, 0)),
                                 Observation('obj_05', pose(0.1, 0))])
    again = tracker.update(1 * SECOND, [Observation('obj_05', pose(0.1, 0))])
    assert again[0].instance == 'obj_05_1' and tracker.resets == 1
    later = tracker.update(100 * SECOND, [Observation('obj_05', pose(0.1, 0))])
    assert later[0].instance == 'obj_05_1' and tracker.resets == 2


def test_symmetric_part_is_reported_in_the_nearest_equivalent_rotation():
    flip = make_transform(rotation_about_axis(np.array([0, 0, 1.0]), np.pi), np.zeros(3))
    tracker = InstanceTracker(symmetries={'obj_05': np.stack([np.eye(4), flip])})
    T0 = pose(0, 0, yaw_deg=10)
    tracker.update(0, [Observation('obj_05', T0)])
    # the stage reports the same part in the other symmetric rotation (180° away)
    tracked = tracker.update(SECOND // 10, [Observation('obj_05', T0 @ flip)])
    assert tracked[0].instance == 'obj_05_1' and not tracked[0].new
    np.testing.assert_allclose(tracked[0].T_world_part, T0, atol=1e-9)
    # without the symmetry the same report would be a turned part: a new name
    plain = InstanceTracker()
    plain.update(0, [Observation('obj_05', T0)])
    assert plain.update(SECOND // 10, [Observation('obj_05', T0 @ flip)])[0].new


def test_nearest_equivalent_angle():
    T = pose(0, 0, yaw_deg=40)
    _, angle = nearest_equivalent(T, pose(0, 0), None)
    assert angle == pytest.approx(40.0)


@pytest.mark.parametrize('field', ['gate_m', 'gate_deg', 'ttl_s', 'time_jump_s'])
def test_params_reject_non_positive(field):
    with pytest.raises(ValueError, match=field):
        TrackParams(**{field: 0.0})


class Item:
    def __init__(self, instance):
        self.instance, self.part = instance, instance.rsplit('_', 1)[0]


def test_request_takes_the_next_frame_after_it():
    import threading

    from tlessbot_ros.core.track import RequestBook
    book = RequestBook()
    book.on_frame(1, [Item('obj_05_1')])   # before the request: not its answer
    request = book.open(parts=['obj_05'])
    waiter = threading.Thread(target=request.wait, args=(10.0,))
    waiter.start()
    assert book.on_frame(2, [Item('obj_05_1'), Item('obj_07_1')]) == 1
    waiter.join()
    assert request.done and request.stamp_ns == 2
    assert [i.instance for i in request.answer] == ['obj_05_1']
    assert book.pending() == 0


def test_request_agreement_of_frames_and_timeout():
    from tlessbot_ros.core.track import RequestBook
    book = RequestBook()
    request = book.open(frames=3)
    book.on_frame(1, [Item('obj_05_1'), Item('obj_07_1')])
    book.on_frame(2, [Item('obj_05_1'), Item('obj_07_1'), Item('obj_09_1')])
    assert not request.wait(0.0)
    book.on_frame(3, [Item('obj_05_1'), Item('obj_09_1')])
    assert request.wait(0.0) and [i.instance for i in request.answer] == ['obj_05_1']
    late = book.open()
    assert not late.wait(0.01)
    assert 'no frame completed within 0.0 s' in book.timeout_reason(0.01)
    with pytest.raises(ValueError, match='frames'):
        book.open(frames=1000)


def test_cancel_wakes_waiting_requests():
    from tlessbot_ros.core.track import RequestBook
    book = RequestBook()
    request = book.open()
    book.cancel_all()
    assert request.wait(0.0) and request.cancelled and request.answer == []
    assert book.pending() == 0
