"""How a stage admits frames (nodes/admission.py), without a ROS graph: no rclpy.init, no node.
The rate cap, and the entrance's backpressure with the callables a node would hand it."""
from __future__ import annotations

import numpy as np
import pytest

pytestmark = pytest.mark.ros   # imports rclpy's message classes; starts nothing


def _views(stamp_ns: int):
    """A one-message frame whose header carries ``stamp_ns``."""
    from tlessbot_ros.conversions.image_cdr import image_to_cdr
    from tlessbot_ros.conversions.messages import message_class
    from tlessbot_ros.nodes.inputs import RawMessage

    data = image_to_cdr(np.zeros((2, 2), np.uint16), '16UC1', stamp_ns=stamp_ns)
    return {'side': {'depth': RawMessage(message_class('sensor_msgs/msg/Image'), bytes(data))}}


class _Graph:
    """What the localiser hands its entrance: whether the last stage reports, what it takes,
    when it reopens its inputs."""

    def __init__(self, reports: bool = True, middle: bool = False) -> None:
        self.reports, self.middle = reports, middle
        self.taken: list[int] = []
        self.reopened: list[bool] = []

    def entrance(self, threaded: bool = True, **params):
        from tlessbot_ros.core.common import AdmissionParams
        from tlessbot_ros.nodes.admission import Entrance
        from tlessbot_ros.nodes.inputs import newest_stamp_ns

        return Entrance(AdmissionParams(**params), last_stage_reports=lambda: self.reports,
                        middle_reports=lambda: self.middle,
                        take=lambda views: self.taken.append(newest_stamp_ns(views)),
                        reopen=self.reopened.append, threaded=threaded)


def test_the_rate_cap_drops_frames_sooner_than_its_period_but_never_held_ones():
    from tlessbot_ros.nodes.admission import RateCap

    cap = RateCap()
    assert cap.allows(5.0, 10.0)
    cap.taken(10.0)
    assert not cap.allows(5.0, 10.1)                  # within 0.2 s: dropped
    assert cap.allows(5.0, 10.1, held=True)           # released at a time jump: taken
    assert cap.allows(5.0, 10.25) and cap.allows(0.0, 10.1)   # 0: no cap
    assert cap.dropped == 1


def test_without_a_reporting_last_stage_every_frame_is_taken():
    graph = _Graph(reports=False)
    entrance = graph.entrance(max_in_flight=1)
    assert all(entrance.admit(_views(stamp)) for stamp in (1, 2, 3))
    assert entrance.in_flight.open_count == 0 and entrance.is_open()


def test_a_refused_frame_waits_and_the_outcome_that_frees_a_slot_takes_it():
    from tlessbot_ros.conversions.outcomes import DONE

    graph = _Graph()
    entrance = graph.entrance(max_in_flight=1)
    assert entrance.admit(_views(10))
    assert not entrance.admit(_views(11)) and not entrance.admit(_views(12))
    assert entrance.dropped == 1 and entrance.in_flight.waiting_stamp_ns == 12
    assert not entrance.is_open()                      # full: the inputs are not read
    entrance.finished_downstream(10, DONE, last_stage=True)
    assert graph.taken == [12] and graph.reopened == [True]
    assert entrance.stats() == {'in_flight': 1, 'entrance_refused': 2, 'entrance_waited': 1,
                                'in_flight_expired': 0}


def test_the_gate_reopens_the_inputs_once_when_the_entrance_opens():
    graph = _Graph()
    entrance = graph.entrance(max_in_flight=1, hold_newest=False)
    assert entrance.admit(_views(10)) and not entrance.is_open()
    assert not entrance.admit(_views(11)) and entrance.dropped == 1   # not held: dropped
    entrance.time_jumped()                             # the open frame belongs to the old time
    assert entrance.is_open() and entrance.is_open()
    assert graph.reopened == [False]                   # once, without a frame to keep


def test_a_frame_this_stage_failed_frees_its_slot_and_a_done_one_does_not():
    from tlessbot_ros.conversions.outcomes import DONE, FAILED

    graph = _Graph()
    entrance = graph.entrance(max_in_flight=1)
    assert entrance.admit(_views(10))
    entrance.finished_here(10, DONE)                   # on its way to the later stages
    assert entrance.in_flight.open_count == 1
    entrance.finished_here(10, FAILED)
    assert entrance.in_flight.open_count == 0


def test_a_second_frame_enters_once_the_middle_stage_passed_the_first_on():
    from tlessbot_ros.conversions.outcomes import DONE

    graph = _Graph(middle=True)
    entrance = graph.entrance(max_in_flight=2, pipeline_min_spare_cores=0.0)
    assert entrance.admit(_views(10))
    assert not entrance.admit(_views(11))              # 10 is before the last stage; 11 waits
    entrance.finished_downstream(10, DONE, last_stage=False)
    assert graph.taken == [11] and entrance.in_flight.open_count == 2


def test_without_a_frame_thread_the_next_frame_takes_the_waiting_one_first():
    from tlessbot_ros.conversions.outcomes import DONE

    graph = _Graph()
    entrance = graph.entrance(threaded=False, max_in_flight=1)
    assert entrance.admit(_views(10)) and not entrance.admit(_views(11))
    entrance.finished_downstream(10, DONE, last_stage=True)
    assert graph.taken == []                           # the outcome's callback takes nothing
    assert not entrance.admit(_views(12))              # 11 goes first and fills the slot
    assert graph.taken == [11] and entrance.in_flight.waiting_stamp_ns == 12


def test_turning_holding_off_drops_the_waiting_frame_and_reads_nothing_that_waited():
    from dataclasses import replace

    graph = _Graph()
    entrance = graph.entrance(max_in_flight=1)
    assert entrance.admit(_views(10)) and not entrance.admit(_views(11))
    entrance.set_params(replace(entrance.in_flight.params, hold_newest=False))
    assert entrance.dropped == 1 and entrance.in_flight.waiting_stamp_ns is None
    assert graph.reopened == [False]
