"""A fitted part's region trimmed to its fitted outline: a shadow or a table piece attached
to a part no longer widens its box (issue 41, core/region_trim.py)."""
from __future__ import annotations

import cv2
import numpy as np
import pytest
import trimesh
from side_scene import SIDE, TABLE

from tlessbot_ros.core.common import MeshRenderer, make_transform, mask_box, rotation_about_axis
from tlessbot_ros.core.metrics import box_iou
from tlessbot_ros.core.params import FitParams
from tlessbot_ros.core.pipeline import PerceptionPipeline, ViewInput
from tlessbot_ros.core.pose import build_database
from tlessbot_ros.core.region_trim import near_outline

YAW = rotation_about_axis([0, 0, 1], np.radians(60))
T_TRUE = make_transform(YAW, [0.004, -0.006, 0.0])


@pytest.fixture(scope='module')
def plate_with_a_shadow():
    """A plate 60 x 30 x 5 mm on the table seen from the side, and its region with a band of
    table 25 px long and 5 px wide attached beside it (a shadow's streak, a piece of the
    table's pattern): (database, views, plate mask, region)."""
    box = trimesh.creation.box(bounds=np.array(((-0.03, -0.015, 0), (0.03, 0.015, 0.005))))
    vertices, faces = np.asarray(box.vertices), np.asarray(box.faces, np.int64)
    flipped = make_transform(rotation_about_axis([1.0, 0.0, 0.0], np.pi), [0, 0, 0.005])
    db = build_database([(1, vertices, faces, [(np.eye(4), 0.5), (flipped, 0.5)], None)],
                        intrinsics=SIDE.intrinsics, T_world_camera=SIDE.T_world_camera)
    renderer = MeshRenderer()
    renderer.add_mesh(*TABLE)
    renderer.add_mesh(vertices, faces, T_TRUE)
    view = renderer.render(SIDE.intrinsics, SIDE.T_world_camera)
    plate = view.instance >= 1
    rgb = np.full(plate.shape + (3,), 120, np.uint8)
    rgb[plate] = (70, 100, 190)
    noise = np.random.default_rng(1).normal(0.0, 0.0005, plate.shape)
    depth = np.where(view.depth_m > 0, view.depth_m + noise, 0).astype(np.float32)
    grown = cv2.dilate(plate.astype(np.uint8), np.ones((51, 51), np.uint8)).astype(bool)
    ys, xs = np.nonzero(plate)
    shadow = grown & ~plate & (np.arange(plate.shape[1])[None, :] > np.median(xs))
    shadow &= np.abs(np.arange(plate.shape[0])[:, None] - np.median(ys)) < 3
    views = {'side': ViewInput(rgb, depth, SIDE.intrinsics, SIDE.T_world_camera)}
    return db, views, plate, plate | shadow


def _found(db, views, region, **fit):
    labels = {'side': region.astype(np.uint16)}
    pipeline = PerceptionPipeline(templates=db, fit_params=FitParams(**fit))
    found = pipeline.estimate_poses(views, labels, {1: (1,)})
    return found, labels['side']


def test_a_shadow_attached_to_a_part_is_trimmed_off_its_region(plate_with_a_shadow):
    """The plate is fitted where it lies; the band of table beside it lies outside the fitted
    outline: trimmed, the box the plate's (main's code: the region and box keep the band)."""
    db, views, plate, region = plate_with_a_shadow
    assert box_iou(mask_box(region), mask_box(plate)) < 0.7   # the band widens the box
    kept, labels = _found(db, views, region, trim_to_fit_px=0)   # the rule off (main)
    assert np.array_equal(labels > 0, region)
    found, labels = _found(db, views, region)
    assert len(found) == 1 and found[0].pose is not None
    T_world = SIDE.T_world_camera @ found[0].pose.T_camera_object
    assert np.linalg.norm(T_world[:2, 3] - T_TRUE[:2, 3]) < 0.005
    assert np.array_equal(found[0].pose.T_camera_object, kept[0].pose.T_camera_object)
    trimmed = labels == found[0].instance_id
    assert not (trimmed & ~region).any() and (plate & ~trimmed).sum() < 0.02 * plate.sum()
    assert box_iou(mask_box(trimmed), mask_box(plate)) > 0.9
    assert found[0].box == mask_box(trimmed)


def test_a_fit_off_its_region_trims_nothing(plate_with_a_shadow):
    """A fitted outline that its region covers less than ``MIN_SEEN`` of (a fit shifted off
    its region, a part under another) leaves the region as it was."""
    db, views, plate, region = plate_with_a_shadow
    obj = db[1]
    T = np.linalg.inv(SIDE.T_world_camera) @ T_TRUE
    assert near_outline(obj, T, views['side'], region, 3, 0.8) is not None
    shifted = np.linalg.inv(SIDE.T_world_camera) @ make_transform(YAW, [0.004, 0.024, 0.0])
    assert near_outline(obj, shifted, views['side'], region, 3, 0.8) is None


def test_trim_to_fit_px_must_not_be_negative():
    assert FitParams().trim_to_fit_px == 3
    with pytest.raises(ValueError, match='trim_to_fit_px must be >= 0'):
        FitParams(trim_to_fit_px=-1)
