"""Frame outcomes: what a stage node did with a two-view frame, as a ``std_msgs/Header``.

The header's ``stamp`` is the frame's stamp (the newest stamp among its input messages, the
same in every stage) and its ``frame_id`` the outcome: ``done`` (processed), ``dropped``
(complete but not processed: a newer frame replaced it) or ``failed`` (processing raised). A
Header is the smallest standard message that carries a stamp and a word, and
``ros2 topic echo /pose_estimator/frames`` reads it as it is.
"""
from __future__ import annotations

from typing import Any

from tlessbot_ros.conversions.messages import MessageFactory, make_header, stamp_to_ns

DONE, DROPPED, FAILED = 'done', 'dropped', 'failed'
OUTCOMES = (DONE, DROPPED, FAILED)


def frame_outcome(stamp_ns: int, outcome: str, factory: MessageFactory | None = None) -> Any:
    """The Header reporting ``outcome`` for the frame stamped ``stamp_ns``."""
    if outcome not in OUTCOMES:
        raise ValueError(f'outcome must be one of {OUTCOMES}, got {outcome!r}')
    return make_header(outcome, stamp_ns, factory)


def read_frame_outcome(msg: Any) -> tuple[int, str]:
    """``(stamp_ns, outcome)`` of a frame-outcome Header.

    Raises:
        ValueError: the header's frame_id is not an outcome.
    """
    if msg.frame_id not in OUTCOMES:
        raise ValueError(f'not a frame outcome: frame_id {msg.frame_id!r}')
    return stamp_to_ns(msg.stamp), msg.frame_id
