"""Image CDR without rclpy messages: the same bytes as rclpy, read back without a copy."""
from __future__ import annotations

import numpy as np
import pytest

from tlessbot_ros.conversions import array_to_image, image_to_array, stamp_to_ns
from tlessbot_ros.conversions.image_cdr import image_from_cdr, image_to_cdr

pytestmark = pytest.mark.ros

CASES = [((2, 3), '16UC1', np.uint16, ''), ((4, 5, 3), 'rgb8', np.uint8, 'side_color_optical'),
         ((3, 2, 3), '16UC3', np.uint16, 'ab'), ((2, 2), '32FC1', np.float32, 'top_frame'),
         ((1, 7, 4), 'bgra8', np.uint8, 'x')]


@pytest.mark.parametrize('shape, encoding, dtype, frame_id', CASES)
def test_bytes_read_and_written_like_rclpy(shape, encoding, dtype, frame_id):
    from rclpy.serialization import deserialize_message, serialize_message
    from sensor_msgs.msg import Image

    array = (np.random.default_rng(len(frame_id)).random(shape) * 200).astype(dtype)
    stamp_ns = 1_700_000_123_456_789_012
    reference = serialize_message(array_to_image(array, encoding, frame_id=frame_id,
                                                 stamp_ns=stamp_ns))
    ours = image_to_cdr(array, encoding, frame_id=frame_id, stamp_ns=stamp_ns)
    assert len(ours) == len(reference)
    back = deserialize_message(ours, Image)          # rclpy reads what we write
    np.testing.assert_array_equal(image_to_array(back), array)
    assert (back.header.frame_id, back.encoding) == (frame_id, encoding)
    for raw in (ours, reference):                    # we read what rclpy writes
        image = image_from_cdr(raw)
        np.testing.assert_array_equal(image_to_array(image), array)
        assert stamp_to_ns(image.header.stamp) == stamp_ns
        assert (image.header.frame_id, image.encoding, image.step) == \
            (frame_id, encoding, back.step)


def test_reading_does_not_copy_the_pixels():
    raw = image_to_cdr(np.zeros((480, 640, 3), np.uint16), '16UC3')
    pixels = image_to_array(image_from_cdr(raw))
    assert np.shares_memory(pixels, np.frombuffer(raw, np.uint8))
    assert not pixels.flags.writeable


@pytest.mark.parametrize('cut', [0, 3, 10, 17, 30, -1])
def test_truncated_or_foreign_bytes_raise_value_error(cut):
    raw = image_to_cdr(np.ones((2, 3), np.uint16), '16UC1', frame_id='f')
    with pytest.raises(ValueError):
        image = image_from_cdr(raw[:cut] if cut else b'\x12\x34' + raw[2:])
        image_to_array(image)
