"""A drilled block fitted upside down: its box fits the depth either way up and only its 6 mm
holes tell the turns apart. The fit turned as it is (its own placement error shared by both
poses) shows the views the holes' difference alone, and the votes turn the block back."""
from __future__ import annotations

import numpy as np
import pytest
from side_scene import SIDE, drilled_block, side_scene

from tlessbot_ros.core.common import (
    depth_to_points,
    make_transform,
    plane_of_frame,
    rotation_about_axis,
    rotation_angle_deg,
)
from tlessbot_ros.core.pose import PoseParams, Refiner, TurnParams, near_turns
from tlessbot_ros.core.pose.flat import FlatCheck, FlatParams, ViewEvidence
from tlessbot_ros.core.pose.half_turns import choose_half_turn, self_half_turns


@pytest.fixture(scope='module')
def block():
    """The generator's drilled block (40 x 30 x 20 mm, two vertical holes, a cross hole,
    chamfered vertical edges): (vertices m, faces), its templates on its base, the object."""
    return drilled_block()


def _axis(S: np.ndarray) -> np.ndarray:
    w, V = np.linalg.eig(S[:3, :3])
    return np.real(V[:, np.argmin(np.abs(w - 1))])


def _scene(v, f, yaw_deg: float):
    lift = -float(v[:, 2].min())
    T_world_object = make_transform(rotation_about_axis(np.array([0, 0, 1.0]),
                                                        np.radians(yaw_deg)), [0.01, -0.01, lift])
    rgb, depth, mask = side_scene(v, f, T_world_object, noise_m=0.0005, shaded=True)
    points, _ = depth_to_points(depth, SIDE.intrinsics.K, mask=mask)
    view = ViewEvidence(rgb, mask, SIDE.intrinsics, np.eye(4), depth,
                        plane_of_frame(SIDE.T_world_camera), np.zeros_like(mask))
    return np.linalg.inv(SIDE.T_world_camera) @ T_world_object, [view], points


def test_the_box_half_turns_are_near_symmetric_turns(block):
    _, _, obj = block
    near = near_turns(obj)
    for e in np.eye(3):   # about each of the box's axes: listed by both
        S = min(self_half_turns(obj), key=lambda S: -abs(_axis(S) @ e))
        assert abs(_axis(S) @ e) > 0.99
        assert any(rotation_angle_deg(S[:3, :3], N[:3, :3]) < 2.5 for N in near)


def _fit_error():
    """A fit's own placement error: 1.5° about the vertical and 1 mm along the table."""
    return make_transform(rotation_about_axis(np.array([0, 0, 1.0]), np.radians(1.5)),
                          [0.001, 0.0, 0.0])


@pytest.mark.parametrize('yaw_deg', [20.0, 65.0])
@pytest.mark.parametrize('axis', [0, 2])
def test_a_block_fitted_upside_down_or_about_the_vertical_is_turned_back(block, yaw_deg, axis):
    v, f, obj = block
    T_true, views, points = _scene(v, f, yaw_deg)
    check = FlatCheck(Refiner(PoseParams()), FlatParams())
    scene = check.prepared_cloud(obj, points)
    # a half turn about the block's long axis (upside down) or its vertical one
    S = min(self_half_turns(obj), key=lambda S: -abs(_axis(S) @ np.eye(3)[axis]))
    turned, info = choose_half_turn(check, obj, T_true @ S @ _fit_error(), scene, views,
                                    TurnParams())
    assert info['half_winner'] > 0 and info['half_decided'] == 1.0, info
    assert rotation_angle_deg(turned[:3, :3], T_true[:3, :3]) < 5.0, info


@pytest.mark.parametrize('yaw_deg', [20.0, 65.0])
def test_a_right_block_fit_with_its_own_error_stays(block, yaw_deg):
    """The fit 1.5° and 1 mm off: its half turns refitted to the depth lose that error, and
    their outline then explains more pixels than the fit's holes do (they turned it over);
    turned as they are, they share it, and the holes keep the fit."""
    v, f, obj = block
    T_true, views, points = _scene(v, f, yaw_deg)
    check = FlatCheck(Refiner(PoseParams()), FlatParams())
    scene = check.prepared_cloud(obj, points)
    T_fit = T_true @ _fit_error()
    kept, info = choose_half_turn(check, obj, T_fit, scene, views, TurnParams())
    assert info['half_winner'] == 0.0 and np.array_equal(kept, T_fit), info
