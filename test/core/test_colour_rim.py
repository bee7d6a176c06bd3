"""A region's ring of blended colour peeled off: a small part's box is the part's own, on a
plain or a checkered table (issue 41, core/colour_rim.py)."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from tlessbot_ros.core.colour_rim import peel_colour_rims, rim_pixels_to_drop
from tlessbot_ros.core.common import CameraIntrinsics, mask_box
from tlessbot_ros.core.frame import Detection, ViewInput
from tlessbot_ros.core.localise.colour import rgb_to_lab
from tlessbot_ros.core.metrics import box_iou
from tlessbot_ros.core.params import FitParams

SHAPE = (80, 100)
FINE = 8   # the scene is drawn this many times finer, then each pixel averages its block


def _scene(centre_px: tuple[float, float], radius_px: float, part_rgb, checker_px: int = 0):
    """(rgb (H, W, 3) uint8, part mask (H, W) bool): a disc of ``radius_px`` on a table grey,
    or checkered in two greys in squares of ``checker_px``; each pixel's colour is the
    average over its area (a rim pixel blends both), the mask holds the pixels whose centre
    lies on the disc."""
    h, w = SHAPE[0] * FINE, SHAPE[1] * FINE
    ys, xs = (np.mgrid[0:h, 0:w] + 0.5) / FINE
    table = np.full((h, w, 3), 170.0)
    if checker_px:
        dark = ((ys // checker_px + xs // checker_px) % 2).astype(bool)
        table[dark] = 95.0
    disc = (xs - centre_px[0]) ** 2 + (ys - centre_px[1]) ** 2 <= radius_px ** 2
    fine = np.where(disc[..., None], np.asarray(part_rgb, float), table)
    rgb = cv2.resize(fine, SHAPE[::-1], interpolation=cv2.INTER_AREA)
    cy, cx = np.mgrid[0:SHAPE[0], 0:SHAPE[1]] + 0.5
    mask = (cx - centre_px[0]) ** 2 + (cy - centre_px[1]) ** 2 <= radius_px ** 2
    return np.clip(np.rint(rgb), 0, 255).astype(np.uint8), mask


def _with_ring(mask: np.ndarray) -> np.ndarray:
    """The localiser's region of a part: its mask and the ring of pixels touching it."""
    return cv2.dilate(mask.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)


def _peeled(rgb: np.ndarray, region: np.ndarray, below: float = 0.5,
            **kw) -> tuple[np.ndarray, Detection]:
    labels = {'side': np.where(region, 3, 0).astype(np.uint16)}
    detection = Detection(obj_id=1, instance_id=3, view='side', box=mask_box(region))
    views = {'side': ViewInput(rgb, None, CameraIntrinsics(SHAPE[1], SHAPE[0], np.eye(3)))}
    peel_colour_rims(views, labels, [detection], below, **kw)
    return labels['side'] == 3, detection


@pytest.mark.parametrize('checker_px', [0, 6])
def test_the_blended_ring_of_a_part_ten_pixels_across_leaves_its_box(checker_px):
    """A dark nut 10 px across whose region holds the ring of table-blended pixels around it:
    its box overlaps the nut's by under 0.7; peeled, the box is the nut's (main's code keeps
    the ring: no such step)."""
    rgb, nut = _scene((40.3, 30.6), 5.0, (40, 40, 60), checker_px)
    region = _with_ring(nut)
    assert box_iou(mask_box(region), mask_box(nut)) < 0.7
    peeled, detection = _peeled(rgb, region)
    assert box_iou(mask_box(peeled), mask_box(nut)) > 0.8
    assert detection.box == mask_box(peeled)
    assert np.count_nonzero(nut & ~peeled) <= 2   # the nut's own pixels stay


def test_a_large_parts_ring_is_peeled_and_its_inside_kept():
    """A bright part 40 px across on a checkered table: the ring goes, every pixel whose
    centre lies on the part more than a pixel in from its outline stays."""
    rgb, part = _scene((50.2, 40.4), 20.0, (200, 60, 40), 6)
    peeled, _ = _peeled(rgb, _with_ring(part))
    inner = cv2.erode(part.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    assert not (inner & ~peeled).any()
    assert np.count_nonzero(peeled & ~part) <= 2
    assert box_iou(mask_box(peeled), mask_box(part)) > 0.95


def test_a_part_of_the_tables_colour_keeps_its_ring():
    """Inside and outside alike (less than MIN_CONTRAST apart): the blend share is noise and
    no pixel is dropped."""
    rgb, part = _scene((40.3, 30.6), 6.0, (174, 170, 168))
    region = _with_ring(part)
    assert not rim_pixels_to_drop(rgb_to_lab(rgb), region, 0.5).any()


def test_off_and_box_mode_leave_the_region():
    rgb, nut = _scene((40.3, 30.6), 5.0, (40, 40, 60))
    region = _with_ring(nut)
    assert (_peeled(rgb, region, 0.0)[0] == region).all()
    assert (_peeled(rgb, region, box_mode=True)[0] == region).all()


def test_the_share_is_checked():
    with pytest.raises(ValueError, match='rim_colour_below'):
        FitParams(rim_colour_below=1.5)
    assert FitParams().rim_colour_below == 0.0   # off: it costs parts drawn with hard edges
