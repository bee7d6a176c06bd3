"""The aligned votes on a smoothed depth (a RealSense's): the depth's spread is measured on the
part (:func:`~tlessbot_ros.core.pose.flat_align.depth_spread_px`)."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from tlessbot_ros.core.pose.flat_align import depth_spread_px

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
