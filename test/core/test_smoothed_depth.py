"""The aligned votes on a smoothed depth (a RealSense's): the depth's spread is measured on the
part (:func:`~tlessbot_ros.core.pose.flat_align.depth_spread_px`)."""
from __future__ import annotations

import cv2
import numpy as np
import pytest
from side_scene import SIDE, holed_plate, side_scene

from tlessbot_ros.core.common import (
    make_transform,
    plane_of_frame,
    raycasting_scene,
    rotation_about_axis,
)
from tlessbot_ros.core.pose.flat import FlatParams, ViewEvidence
from tlessbot_ros.core.pose.flat_align import depth_spread_px, view_votes
from tlessbot_ros.core.pose.flat_turns import outline_half_turns

PAD = 6


def _plate() -> tuple[np.ndarray, np.ndarray]:
    """(hit, height) over a 60 x 80 window grown by ``PAD``: a 4 mm plate with a 4 px hole."""
    hit = np.zeros((60 + 2 * PAD, 80 + 2 * PAD), bool)
    hit[20:50, 20:70] = True
    hit[30:34, 30:34] = False
    return hit, np.where(hit, 0.004, 0.0)


def _measured(height: np.ndarray, sigma: float) -> np.ndarray:
    blurred = cv2.GaussianBlur(height, (0, 0), sigma) if sigma > 0 else height
    return blurred[PAD:-PAD, PAD:-PAD].copy()


@pytest.mark.parametrize('sigma', [0.0, 2.0, 4.0])
def test_the_depth_s_spread_is_measured_on_the_part(sigma):
    render = _plate()
    region = np.ones((60, 80), bool)
    assert depth_spread_px(_measured(render[1], sigma), render, PAD, region) == sigma


def test_a_per_pixel_noise_is_no_spread():
    render = _plate()
    noise = np.random.default_rng(4).normal(0, 0.001, (60, 80))
    measured = _measured(render[1], 0.0) + noise
    assert depth_spread_px(measured, render, PAD, np.ones((60, 80), bool)) == 0.0


def test_too_few_pixels_with_depth_are_no_spread():
    render = _plate()
    measured = np.full((60, 80), np.nan)
    measured[:3, :3] = 0.0
    assert depth_spread_px(measured, render, PAD, np.ones((60, 80), bool)) == 0.0


@pytest.mark.parametrize('sigma', [0.0, 2.0, 4.0])
def test_no_turn_of_a_plate_outvotes_it_on_a_smoothed_depth(sigma):
    # a guard, not a gain: on this plate (an 8 mm hole) main's votes hold too
    vertices, faces = holed_plate()
    T_world = make_transform(rotation_about_axis([0, 0, 1], np.radians(23.0)),
                             [0.004, -0.006, 0.0])
    _, depth, mask = side_scene(vertices, faces, T_world, noise_m=0.0005, seed=3)
    if sigma > 0:
        valid = np.isfinite(depth) & (depth > 0)
        blurred = cv2.GaussianBlur(np.where(valid, depth, 0).astype(np.float32), (0, 0), sigma)
        depth = np.where(valid, blurred, depth)
    evidence = [ViewEvidence(None, mask, SIDE.intrinsics, np.eye(4), depth,
                             plane_of_frame(SIDE.T_world_camera), None)]
    T = np.linalg.inv(SIDE.T_world_camera) @ T_world
    points = vertices.astype(np.float64)
    poses = [T] + [T @ turn for turn in outline_half_turns(points)]
    params = FlatParams()
    votes = view_votes([raycasting_scene(vertices, faces)] * 4, poses, points, evidence,
                       align_at_1m_m=params.align_at_1m_m, tolerance_m=params.depth_tolerance_m)
    assert all(votes[k, 0] <= votes[0, k] for k in range(1, 4))


def test_a_pose_that_misses_the_depth_measures_no_spread():
    render = _plate()
    measured = _measured(render[1], 4.0)
    measured[:, :40] += 0.006       # half the window 6 mm above what the pose explains
    region = np.ones((60, 80), bool)
    assert depth_spread_px(measured, render, PAD, region) == 4.0
    assert depth_spread_px(measured, render, PAD, region, max_error_m=0.002) == 0.0


def _aligned_plate_view(first_misplaced: bool):
    """The holed plate on a depth smoothed by 3 px, seen by the side camera: the
    :class:`AlignedView` of the plate's pose and of the plate stood up 40° about its long
    axis, the one given first measuring the spread; with the plain renderings."""
    from tlessbot_ros.core.pose.flat_align import aligned_view, render_heights, shift_px
    from tlessbot_ros.core.pose.silhouette import window

    vertices, faces = holed_plate()
    T_world = make_transform(rotation_about_axis([0, 0, 1], np.radians(23.0)),
                             [0.004, -0.006, 0.0])
    _, depth, _ = side_scene(vertices, faces, T_world, noise_m=0.0005, seed=3)
    valid = np.isfinite(depth) & (depth > 0)
    blurred = cv2.GaussianBlur(np.where(valid, depth, 0).astype(np.float32), (0, 0), 3.0)
    depth = np.where(valid, blurred, depth)
    T = np.linalg.inv(SIDE.T_world_camera) @ T_world
    up = make_transform(rotation_about_axis([1, 0, 0], np.radians(40.0)), [0, 0, 0.01])
    poses = [T @ up, T] if first_misplaced else [T, T @ up]
    points, scene = vertices.astype(np.float64), raycasting_scene(vertices, faces)
    params = FlatParams()
    pad = shift_px(SIDE.intrinsics, points, poses[0], params.align_at_1m_m)
    box = window(points, poses, SIDE.intrinsics, margin_px=pad + 4)
    plane = plane_of_frame(SIDE.T_world_camera)
    x0, y0, w, h = box
    grown = (x0 - pad, y0 - pad, w + 2 * pad, h + 2 * pad)
    view = aligned_view([(scene, T_k) for T_k in poses], box, pad, SIDE.intrinsics, plane,
                        rgb=None, depth_m=depth, others=None,
                        tolerance_m=params.depth_tolerance_m)
    return view, [render_heights(scene, T_k, SIDE.intrinsics, grown, plane)[1] for T_k in poses]


@pytest.mark.parametrize('first_misplaced', [False, True])
def test_the_renderings_are_blurred_where_the_measuring_pose_meets_the_depth(first_misplaced):
    """Measured at the plate's pose, the spread blurs both renderings; measured at a pose that
    misses the depth (stood up), the blur would only lower that pose's error: none."""
    view, plain = _aligned_plate_view(first_misplaced)
    blurred = [not np.allclose(rendered, plain_k)
               for (_, rendered), plain_k in zip(view.renders, plain)]
    assert blurred == [not first_misplaced] * 2
