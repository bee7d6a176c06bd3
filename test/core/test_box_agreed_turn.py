"""A box round both of whose rounds, the poses as they are and refined on the image, name one
turn duel by duel, each short of the clear margin: with ``box_agreed_turn`` (the default) the
turn is taken where it changes at least ``box_agreed_min_px`` pixels of the fit
(:func:`~tlessbot_ros.core.pose.half_turns.turn_seen_px`); a turn the rig hardly sees, or the
rule off, leaves the open round to the fit."""
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


def _winner(monkeypatch, as_is: np.ndarray, refined: np.ndarray, params: TurnParams,
            seen_px: int = 40) -> tuple[int, bool]:
    """``_box_winner`` on the vote matrices, the turn changing ``seen_px`` pixels of the fit."""
    from tlessbot_ros.core.pose import flat_align, half_turns, image_refine, turns

    monkeypatch.setattr(flat_align, 'view_votes', lambda *args, **kwargs: as_is)
    monkeypatch.setattr(flat_align, 'pose_spread_px', lambda *args, **kwargs: 0.0)
    monkeypatch.setattr(image_refine, 'refine_on_image',
                        lambda mesh, poses, *args, **kwargs: (poses, refined))
    monkeypatch.setattr(half_turns, 'hull_moved_m', lambda *args: 0.0)
    # raising=False: where the rule has no guard the count is not asked for
    monkeypatch.setattr(half_turns, 'turn_seen_px', lambda *args: seen_px, raising=False)
    monkeypatch.setattr(turns, 'surface_centre', lambda obj: np.zeros(3))
    check = FlatCheck(Refiner(PoseParams()), FlatParams())
    obj = type('Obj', (), {'model_points': np.zeros((3, 3), np.float32)})()
    return half_turns._box_winner(check, obj, None, [np.eye(4)] * 4, [], params)


AGREED = TurnParams(box_agreed_turn=True)


def test_a_turn_both_rounds_name_by_every_duel_is_taken_by_default(monkeypatch):
    assert _winner(monkeypatch, AS_IS, REFINED, TurnParams()) == (3, True)


def test_the_rule_off_leaves_the_open_round_to_the_fit(monkeypatch):
    assert _winner(monkeypatch, AS_IS, REFINED, TurnParams(box_agreed_turn=False)) == (3, False)


@pytest.mark.parametrize('seen_px', [0, 2, 19])
def test_a_turn_the_rig_hardly_sees_keeps_the_fit(monkeypatch, seen_px):
    # a 10 mm nut's half turns change about 2 pixels: its two rounds agree by chance
    assert _winner(monkeypatch, AS_IS, REFINED, AGREED, seen_px) == (3, False)


def test_a_lower_floor_takes_the_turn(monkeypatch):
    assert _winner(monkeypatch, AS_IS, REFINED, TurnParams(box_agreed_min_px=2), 2) == (3, True)


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


@pytest.fixture(scope='module')
def block():
    from side_scene import block_with_box_turns

    return block_with_box_turns()


def _seen_px(v, f, model_points, box, yaw_deg: float) -> list[int]:
    """:func:`~tlessbot_ros.core.pose.half_turns.turn_seen_px` of each box turn of a part
    (vertices m, faces) lying on a side before the side camera, turned ``yaw_deg``."""
    import open3d as o3d
    from side_scene import block_on_a_side, side_evidence, side_scene

    from tlessbot_ros.core.pose.half_turns import turn_seen_px

    mesh = o3d.t.geometry.RaycastingScene()
    mesh.add_triangles(o3d.core.Tensor(v.astype(np.float32)), o3d.core.Tensor(f.astype(np.uint32)))
    obj = type('Obj', (), {'model_points': np.asarray(model_points, np.float32)})()
    T_world_object = block_on_a_side(v, yaw_deg)
    rgb, depth, mask = side_scene(v, f, T_world_object, noise_m=0.0, shaded=True)
    T, views, _ = side_evidence(rgb, depth.astype(np.float32), mask, T_world_object)
    return [turn_seen_px(obj, mesh, T, T @ S, views) for S in box]


@pytest.mark.parametrize('yaw_deg', [-20.0, 25.0])
def test_a_drilled_block_s_box_turns_change_enough_pixels(block, yaw_deg):
    v, f, obj, box = block
    assert min(_seen_px(v, f, obj.model_points, box, yaw_deg)) >= TurnParams().box_agreed_min_px


@pytest.mark.parametrize('yaw_deg', [-20.0, 25.0])
def test_a_small_block_s_box_turns_change_too_few_pixels(block, yaw_deg):
    # the block at half its size (20 x 15 x 10 mm, 3 mm holes): its turns hardly show
    v, f, obj, box = block
    half = [S * np.array([[1, 1, 1, 0.5]] * 3 + [[1, 1, 1, 1]]) for S in box]   # about points / 2
    seen = _seen_px(v / 2, f, obj.model_points / 2, half, yaw_deg)
    assert max(seen) < TurnParams().box_agreed_min_px
