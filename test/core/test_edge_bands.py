"""A thin band along a fitted part's edge is that edge, not a part (issue 41,
core/edge_bands.py)."""
from __future__ import annotations

import cv2
import numpy as np
import pytest
import trimesh
from side_scene import SIDE, TABLE

from tlessbot_ros.core.common import MeshRenderer, make_transform, rotation_about_axis
from tlessbot_ros.core.edge_bands import is_edge_band
from tlessbot_ros.core.params import FitParams
from tlessbot_ros.core.pipeline import PerceptionPipeline, ViewInput
from tlessbot_ros.core.pose import build_database

YAW = rotation_about_axis([0, 0, 1], np.radians(30))


@pytest.fixture(scope='module')
def bar():
    """A bar 60 x 20 x 20 mm on the table in the side view, and a band 4 px wide along its
    outline (the smoothed depth's edge, lifted 4 mm): (views, labels, template database)."""
    box = trimesh.creation.box(bounds=np.array(((-0.03, -0.01, 0), (0.03, 0.01, 0.02))))
    vertices, faces = np.asarray(box.vertices), np.asarray(box.faces, np.int64)
    db = build_database([(1, vertices, faces, [(np.eye(4), 1.0)], None)],
                        intrinsics=SIDE.intrinsics, T_world_camera=SIDE.T_world_camera)
    renderer = MeshRenderer()
    renderer.add_mesh(*TABLE)
    renderer.add_mesh(vertices, faces, make_transform(YAW, [0.0, 0.0, 0.0]))
    view = renderer.render(SIDE.intrinsics, SIDE.T_world_camera)
    part = view.instance >= 1
    ring = cv2.dilate(part.astype(np.uint8), np.ones((9, 9), np.uint8)).astype(bool) & ~part
    labels = np.where(part, 1, np.where(ring, 2, 0)).astype(np.uint16)
    depth = view.depth_m.copy()
    depth[ring] -= 0.004
    noise = np.random.default_rng(1).normal(0.0, 0.0005, labels.shape)
    depth = np.where(depth > 0, depth + noise, 0).astype(np.float32)
    rgb = np.full(labels.shape + (3,), 120, np.uint8)
    rgb[part] = (70, 100, 190)
    return {'side': ViewInput(rgb, depth, SIDE.intrinsics, SIDE.T_world_camera)}, labels, db


def test_the_band_along_a_fitted_part_is_erased_and_not_reported(bar):
    views, labels, db = bar
    kept = {'side': labels.copy()}
    # off: the band stays a region (main's code; same_part.py would join it to the bar, its
    # fit filling the bar's space)
    pipeline = PerceptionPipeline(templates=db, fit_params=FitParams(edge_band_px=0,
                                                                     same_part_share=0.0))
    pipeline.estimate_poses(views, kept, {1: (1,), 2: (1,)})
    assert (kept['side'] == 2).any()
    erased = {'side': labels.copy()}
    found = PerceptionPipeline(templates=db).estimate_poses(views, erased, {1: (1,), 2: (1,)})
    assert [d.instance_id for d in found] == [1] and found[0].pose is not None
    assert not (erased['side'] == 2).any()
    assert (erased['side'] == 1).sum() > 0.9 * (labels == 1).sum()


def test_only_a_band_hugging_a_larger_region_is_one():
    image = np.zeros((40, 60), np.uint16)
    image[10:30, 10:40] = 1                  # the part
    image[10:30, 40:44] = 2                  # a band 4 px wide along its edge
    image[10:30, 46:58] = 3                  # a part 12 px wide, 2 px beside the band
    assert is_edge_band(image, 2, 1, 6)
    assert not is_edge_band(image, 2, 1, 3)  # wider than the band width asked
    assert not is_edge_band(image, 3, 1, 6)  # most of it far from the part
    assert not is_edge_band(image, 1, 2, 6)  # the part is not a band of a smaller region
    assert not is_edge_band(image, 4, 1, 6)  # no such region


def test_the_band_width_is_checked():
    with pytest.raises(ValueError, match='edge_band_px'):
        FitParams(edge_band_px=-1)
    assert FitParams().edge_band_px == 6

