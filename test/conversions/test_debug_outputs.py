"""The pose stage's debug outputs without rclpy: the RViz MarkerArray through RosbagsFactory
(serialised and read back as CDR), and the overlay drawn on arrays, then sent as an rgb8 Image."""
from __future__ import annotations

import numpy as np
import pytest

from tlessbot_ros.conversions import RosbagsFactory, array_to_image, image_to_array, stamp_to_ns
from tlessbot_ros.conversions.markers import (
    ADD,
    DELETEALL,
    POINTS,
    TEXT_VIEW_FACING,
    PartMarker,
    parts_to_marker_array,
)
from tlessbot_ros.core.common import OverlayPart, d415_intrinsics, depth_overlay, make_transform

MARKER_ARRAY = 'visualization_msgs/msg/MarkerArray'


def _pose(z: float) -> np.ndarray:
    return make_transform(np.eye(3), [0.01, -0.02, z])


def test_marker_array_round_trips_through_rosbags_cdr():
    factory = RosbagsFactory()
    model = np.random.default_rng(0).normal(scale=0.02, size=(1000, 3))
    parts = [PartMarker('obj_05 (0.93)', _pose(0.5), 'side_color_optical_frame', model),
             PartMarker('obj_21 (0.81)', _pose(0.6), 'world', model[:10])]
    stamp_ns = 1_700_000_000_123_456_789
    message = parts_to_marker_array(parts, stamp_ns, max_points=300, factory=factory)
    typestore = factory.typestore
    back = typestore.deserialize_cdr(typestore.serialize_cdr(message, MARKER_ARRAY),
                                     MARKER_ARRAY)
    markers = back.markers
    assert [m.action for m in markers] == [DELETEALL, ADD, ADD, ADD, ADD]
    assert [(m.ns, m.id, m.type) for m in markers[1:]] == [
        ('surface', 0, POINTS), ('label', 1, TEXT_VIEW_FACING),
        ('surface', 2, POINTS), ('label', 3, TEXT_VIEW_FACING)]
    surface, label = markers[1], markers[2]
    assert len(surface.points) == len(model[::1000 // 300]) and len(markers[3].points) == 10
    assert surface.points[0].z == pytest.approx(0.5 + model[0, 2])
    assert (surface.scale.x, surface.scale.y, label.scale.z) == (0.003, 0.003, 0.02)
    assert label.text == 'obj_05 (0.93)' and label.pose.orientation.w == 1.0
    assert (label.pose.position.x, label.pose.position.z) == (0.01, 0.5)
    assert surface.header.frame_id == 'side_color_optical_frame'
    assert markers[3].header.frame_id == 'world'
    assert stamp_to_ns(label.header.stamp) == stamp_ns
    assert (surface.color.g, surface.color.a) == (pytest.approx(0.8), 1.0)


def test_overlay_draws_depth_outlines_and_model_points():
    intrinsics = d415_intrinsics(64, 48)
    depth = np.full((48, 64), 0.5, np.float32)
    depth[:, :8] = np.nan                            # invalid: black
    labels = np.zeros((48, 64), np.uint16)
    labels[20:30, 20:30] = 1
    model = np.zeros((50, 3))                        # every point at the part's origin
    part = OverlayPart('obj_05', (20, 20, 10, 10), _pose(0.5), model)
    canvas = depth_overlay(depth, labels, intrinsics.K, [part])
    assert canvas.shape == (48, 64, 3) and canvas.dtype == np.uint8
    assert (canvas[:, :4] == 0).all()
    assert tuple(canvas[20, 25]) == (255, 255, 0)    # the region's outline
    assert (canvas == (0, 255, 0)).all(axis=2).any()  # the projected model point
    image = array_to_image(canvas, 'rgb8', frame_id='side_color_optical_frame',
                           stamp_ns=5, factory=RosbagsFactory())
    np.testing.assert_array_equal(image_to_array(image), canvas)
