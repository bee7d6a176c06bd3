"""Admission by backpressure (core/common/admission.py): frames are admitted only while fewer
than max_in_flight are unfinished, outcomes free their slot, and lost outcomes expire after a
time that follows the observed frame times."""
import pytest

from tlessbot_ros.core.common import AdmissionParams, InFlightFrames


def test_admits_up_to_max_in_flight_then_refuses_until_one_finishes():
    frames = InFlightFrames(AdmissionParams(max_in_flight=2))
    assert frames.try_admit(1, 0.0) and frames.try_admit(2, 0.01)
    assert not frames.try_admit(3, 0.02)
    assert (frames.open_count, frames.refused) == (2, 1)
    assert frames.finish(1, 0.05)
    assert frames.try_admit(4, 0.06)
    assert not frames.finish(3, 0.07)         # never admitted: nothing to finish


def test_zero_max_in_flight_admits_everything():
    frames = InFlightFrames(AdmissionParams(max_in_flight=0))
    assert all(frames.try_admit(stamp, 0.0) for stamp in range(100))
    assert frames.open_count == 0


def test_a_lost_outcome_expires_after_the_floor_when_nothing_was_timed():
    frames = InFlightFrames(AdmissionParams(max_in_flight=1, min_expiry_s=1.0))
    assert frames.try_admit(1, 0.0)
    assert not frames.try_admit(2, 0.99)
    assert frames.try_admit(3, 1.01)
    assert frames.expired == 1


def test_expiry_follows_the_slowest_recent_frame():
    """A slow host (frames take 2 s) must not expire frames that are merely slow."""
    params = AdmissionParams(max_in_flight=1, expiry_factor=3.0, min_expiry_s=0.5)
    frames = InFlightFrames(params)
    now = 0.0
    for stamp in range(5):
        assert frames.try_admit(stamp, now)
        now += 2.0
        assert frames.finish(stamp, now)
    assert frames.expiry_s() == pytest.approx(6.0)
    assert frames.try_admit(10, now)
    assert not frames.try_admit(11, now + 5.9)
    assert frames.try_admit(12, now + 6.1)


def test_frames_dropped_on_the_way_do_not_teach_the_expiry():
    frames = InFlightFrames(AdmissionParams(max_in_flight=1, min_expiry_s=0.5))
    frames.try_admit(1, 0.0)
    frames.finish(1, 30.0, completed=False)
    assert frames.expiry_s() == 0.5


def test_clear_forgets_open_frames():
    frames = InFlightFrames(AdmissionParams(max_in_flight=1))
    frames.try_admit(1, 0.0)
    frames.clear()
    assert frames.try_admit(2, 0.0)


def test_the_newest_refused_frame_waits_for_the_next_free_slot():
    frames = InFlightFrames(AdmissionParams(max_in_flight=1))
    assert frames.try_admit(1, 0.0)
    assert not frames.try_admit(2, 0.1)
    assert frames.hold(2, 'frame 2') is None
    assert frames.take_waiting(0.2) is None            # frame 1 still open: 2 keeps waiting
    assert not frames.try_admit(3, 0.3)
    assert frames.hold(3, 'frame 3') == 'frame 2'      # newer replaces it: 2 is dropped
    assert frames.waiting_stamp_ns == 3
    assert frames.finish(1, 0.4)
    assert frames.take_waiting(0.4) == 'frame 3'       # admitted: it holds the slot now
    assert (frames.open_count, frames.waiting_stamp_ns, frames.released) == (1, None, 1)
    assert frames.take_waiting(0.5) is None
    assert frames.finish(3, 0.6)


def test_without_hold_newest_a_refused_frame_is_dropped_at_once():
    frames = InFlightFrames(AdmissionParams(max_in_flight=1, hold_newest=False))
    assert frames.try_admit(1, 0.0) and not frames.try_admit(2, 0.1)
    assert frames.hold(2, 'frame 2') == 'frame 2'
    assert frames.finish(1, 0.2) and frames.take_waiting(0.2) is None


def test_a_waiting_frame_is_given_up_on_request_and_takes_an_expired_slot():
    frames = InFlightFrames(AdmissionParams(max_in_flight=1, min_expiry_s=1.0))
    frames.try_admit(1, 0.0)
    frames.hold(2, 'frame 2')
    assert frames.drop_waiting() == 'frame 2' and frames.waiting_stamp_ns is None
    frames.hold(3, 'frame 3')
    assert frames.take_waiting(0.5) is None
    assert frames.take_waiting(1.5) == 'frame 3'       # frame 1's outcome was lost
    assert frames.expired == 1


@pytest.mark.parametrize('field, value', [('max_in_flight', -1), ('expiry_factor', 0.5),
                                          ('min_expiry_s', 0.0)])
def test_invalid_params_say_what_to_fix(field, value):
    with pytest.raises(ValueError, match=field):
        AdmissionParams(**{field: value})


def test_a_second_frame_in_flight_needs_a_spare_core_or_a_camera_slower_than_the_graph():
    """pipeline_min_spare_cores: on a busy host at 30 fps one frame is in the graph at a
    time; a free core, or frames that come no faster than the graph finishes them (a bag at
    2 frames/s), let the entrance take a second."""
    host = {'spare': 0.4, 'period': 1 / 30}
    frames = InFlightFrames(AdmissionParams(max_in_flight=2, pipeline_min_spare_cores=1.0),
                            spare_cores=lambda: host['spare'],
                            camera_period_s=lambda: host['period'])
    assert frames.try_admit(1, 0.0)                      # the first needs nothing
    assert not frames.try_admit(2, 0.01)                 # busy host, nothing timed yet
    host['spare'] = 1.2
    assert frames.try_admit(3, 0.02) and not frames.try_admit(4, 0.03)   # max_in_flight
    for stamp, done in ((1, 0.25), (3, 0.27)):           # frames take about 0.25 s
        frames.finish(stamp, done)
    host['spare'] = 0.2
    assert frames.try_admit(5, 0.3) and not frames.try_admit(6, 0.31)    # 30 fps: one
    host['period'] = 0.08                                # 12.5 fps: 3 stages x 0.08 < 0.25 s
    assert not frames.try_admit(7, 0.32)
    host['period'] = 0.09                                # a pipelined graph keeps up: each
    assert frames.try_admit(8, 0.33)                     # frame is worth answering
    unlimited = InFlightFrames(AdmissionParams(max_in_flight=2, pipeline_min_spare_cores=0.0),
                               spare_cores=lambda: 0.0)
    assert unlimited.try_admit(1, 0.0) and unlimited.try_admit(2, 0.0)
    with pytest.raises(ValueError, match='pipeline_min_spare_cores'):
        AdmissionParams(pipeline_min_spare_cores=float('nan'))


def test_a_second_frame_follows_the_first_only_once_it_is_with_the_last_stage():
    """pipeline_behind_last_stage: the second frame's first stages overlap the last stage's
    work on the first, not the middle stage's (where it would catch up and wait inside)."""
    middle = {'reports': True}
    frames = InFlightFrames(AdmissionParams(max_in_flight=2, pipeline_min_spare_cores=0.0),
                            middle_reports=lambda: middle['reports'])
    assert frames.try_admit(1, 0.0)
    assert not frames.try_admit(2, 0.01)              # frame 1 is still before the last stage
    assert not frames.reached_last_stage(99)          # not open: nothing changes
    assert frames.reached_last_stage(1)
    assert frames.try_admit(3, 0.05)                  # frame 1 is with the last stage
    assert not frames.try_admit(4, 0.06)              # max_in_flight
    frames.finish(1, 0.1)
    assert not frames.try_admit(5, 0.11)              # frame 3 is not with the last stage yet
    middle['reports'] = False                         # no middle stage reports: gate off
    assert frames.try_admit(6, 0.12)
    frames.clear()
    middle['reports'] = True
    assert frames.try_admit(7, 0.2) and not frames.reached_last_stage(3)   # forgotten
    off = InFlightFrames(AdmissionParams(max_in_flight=2, pipeline_min_spare_cores=0.0,
                                         pipeline_behind_last_stage=False),
                         middle_reports=lambda: True)
    assert off.try_admit(1, 0.0) and off.try_admit(2, 0.0)


def test_an_expired_frame_no_longer_holds_a_second_back():
    frames = InFlightFrames(AdmissionParams(max_in_flight=2, pipeline_min_spare_cores=0.0,
                                            min_expiry_s=1.0), middle_reports=lambda: True)
    assert frames.try_admit(1, 0.0) and frames.reached_last_stage(1)
    assert frames.try_admit(2, 0.1)          # its outcome is lost
    assert not frames.try_admit(3, 0.5)      # two open
    assert frames.try_admit(4, 1.2)          # both expired: a first frame again
    assert not frames.try_admit(5, 1.25)     # frame 4 is not with the last stage
