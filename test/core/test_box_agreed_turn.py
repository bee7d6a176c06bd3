"""A box round both of whose rounds, the poses as they are and refined on the image, name one
turn duel by duel, each short of the clear margin: with ``box_agreed_turn`` the turn is taken;
by default (off) the open round keeps the fit."""
from __future__ import annotations

import numpy as np
import pytest

from tlessbot_ros.core.pose import PoseParams, Refiner, TurnParams
from tlessbot_ros.core.pose.flat import FlatCheck, FlatParams

# [i, j]: pixels for pose i against pose j; pose 0 is the fit, 1-3 its box turns. Turn 3 wins
# every duel in both rounds, the fit's by a surplus just under the margin at align_min_z 3.
AS_IS = np.array([[0, 11, 9, 6],
                  [17, 0, 16, 2],
                  [11, 12, 0, 9],
                  [21, 11, 22, 0]])
REFINED = np.array([[0, 10, 6, 5],
                    [15, 0, 14, 2],
                    [5, 8, 0, 2],
                    [20, 11, 18, 0]])


def _winner(monkeypatch, as_is: np.ndarray, refined: np.ndarray, params: TurnParams
            ) -> tuple[int, bool]:
    from tlessbot_ros.core.pose import flat_align, half_turns, image_refine, turns

    monkeypatch.setattr(flat_align, 'view_votes', lambda *args, **kwargs: as_is)
    monkeypatch.setattr(flat_align, 'pose_spread_px', lambda *args, **kwargs: 0.0)
    monkeypatch.setattr(image_refine, 'refine_on_image',
                        lambda mesh, poses, *args, **kwargs: (poses, refined))
    monkeypatch.setattr(half_turns, 'hull_moved_m', lambda *args: 0.0)
    monkeypatch.setattr(turns, 'surface_centre', lambda obj: np.zeros(3))
    check = FlatCheck(Refiner(PoseParams()), FlatParams())
    obj = type('Obj', (), {'model_points': np.zeros((3, 3), np.float32)})()
    return half_turns._box_winner(check, obj, None, [np.eye(4)] * 4, [], params)


AGREED = TurnParams(box_agreed_turn=True)


def test_a_turn_both_rounds_name_by_every_duel_is_taken(monkeypatch):
    assert _winner(monkeypatch, AS_IS, REFINED, AGREED) == (3, True)


def test_by_default_the_open_round_keeps_the_fit(monkeypatch):
    assert _winner(monkeypatch, AS_IS, REFINED, TurnParams()) == (3, False)


@pytest.mark.parametrize('duel', [(0, 3), (1, 3), (2, 3)])
def test_a_duel_lost_as_they_are_keeps_the_fit(monkeypatch, duel):
    as_is = AS_IS.copy()
    i, k = duel
    as_is[i, k], as_is[k, i] = as_is[k, i] + 1, as_is[i, k]   # pose i now wins its duel with k
    assert _winner(monkeypatch, as_is, REFINED, AGREED)[1] is False


def test_a_duel_lost_refined_keeps_the_fit(monkeypatch):
    refined = REFINED.copy()
    refined[1, 3], refined[3, 1] = 12, 11
    assert _winner(monkeypatch, AS_IS, refined, AGREED)[1] is False
