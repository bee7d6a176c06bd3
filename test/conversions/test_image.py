import numpy as np
import pytest

from tlessbot_ros.conversions import (
    RclpyFactory,
    RosbagsFactory,
    array_to_image,
    depth_image_to_metres,
    image_to_array,
)
from tlessbot_ros.conversions.image import metres_to_depth_mm

FACTORIES = [pytest.param(RosbagsFactory(), id='rosbags'),
             pytest.param(RclpyFactory(), id='rclpy', marks=pytest.mark.ros)]
rng = np.random.default_rng(0)
SAMPLES = {
    'rgb8': rng.integers(0, 256, (5, 7, 3), dtype=np.uint8),
    'bgr8': rng.integers(0, 256, (5, 7, 3), dtype=np.uint8),
    'mono8': rng.integers(0, 256, (5, 7), dtype=np.uint8),
    'mono16': rng.integers(0, 65536, (5, 7), dtype=np.uint16),
    '16UC1': rng.integers(0, 65536, (5, 7), dtype=np.uint16),
    '16UC3': rng.integers(0, 65536, (5, 7, 3), dtype=np.uint16),
    '32FC1': rng.random((5, 7)).astype(np.float32),
}


@pytest.mark.parametrize('factory', FACTORIES)
@pytest.mark.parametrize('encoding', sorted(SAMPLES))
def test_round_trip(factory, encoding):
    array = SAMPLES[encoding]
    msg = array_to_image(array, encoding, frame_id='top_color_optical_frame',
                         stamp_ns=1_700_000_000_123_456_789, factory=factory)
    assert msg.header.frame_id == 'top_color_optical_frame'
    assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == (1_700_000_000, 123_456_789)
    back = image_to_array(msg)
    assert back.dtype == array.dtype
    np.testing.assert_array_equal(back, array)


def _raw_image(array: np.ndarray, encoding: str, *, pad: int = 0, big_endian: bool = False):
    factory = RosbagsFactory()
    msg = array_to_image(array, encoding, factory=factory)
    typed = array.astype(array.dtype.newbyteorder('>' if big_endian else '<'))
    rows = typed.reshape(array.shape[0], -1).view(np.uint8)
    padded = np.zeros((rows.shape[0], rows.shape[1] + pad), np.uint8)
    padded[:, :rows.shape[1]] = rows
    msg.data = padded.ravel()
    msg.step = padded.shape[1]
    msg.is_bigendian = int(big_endian)
    return msg


def test_row_padding_is_dropped():
    array = SAMPLES['rgb8']
    np.testing.assert_array_equal(image_to_array(_raw_image(array, 'rgb8', pad=11)), array)


@pytest.mark.parametrize('encoding', ['16UC1', '32FC1'])
def test_big_endian_is_decoded(encoding):
    array = SAMPLES[encoding]
    out = image_to_array(_raw_image(array, encoding, pad=6, big_endian=True))
    assert out.dtype.isnative
    np.testing.assert_array_equal(out, array)


@pytest.mark.parametrize('mutate, message', [
    (lambda m: setattr(m, 'encoding', 'yuv422'), 'unsupported image encoding'),
    (lambda m: setattr(m, 'data', m.data[:-1]), 'expected height\\*step'),
    (lambda m: setattr(m, 'height', 0), 'zero size'),
    (lambda m: setattr(m, 'step', 3), 'smaller than'),
])
def test_bad_images_raise_value_error(mutate, message):
    msg = array_to_image(SAMPLES['rgb8'], 'rgb8', factory=RosbagsFactory())
    mutate(msg)
    with pytest.raises(ValueError, match=message):
        image_to_array(msg)


def test_array_to_image_rejects_mismatched_dtype():
    with pytest.raises(ValueError, match='dtype'):
        array_to_image(np.zeros((4, 4), np.float64), '32FC1', factory=RosbagsFactory())
    with pytest.raises(ValueError, match='channel'):
        array_to_image(np.zeros((4, 4), np.uint8), 'rgb8', factory=RosbagsFactory())


def test_depth_in_metres_marks_invalid_as_nan():
    mm = np.array([[0, 1000], [1234, 65535]], np.uint16)
    depth = depth_image_to_metres(array_to_image(mm, '16UC1', factory=RosbagsFactory()))
    assert np.isnan(depth[0, 0])
    np.testing.assert_allclose(depth[~np.isnan(depth)], [1.0, 1.234, 65.535], rtol=1e-6)
    metres = np.array([[np.nan, 0.5], [-1.0, np.inf]], np.float32)
    depth = depth_image_to_metres(array_to_image(metres, '32FC1', factory=RosbagsFactory()))
    assert np.isnan(depth).sum() == 3 and depth[0, 1] == np.float32(0.5)
    np.testing.assert_array_equal(metres_to_depth_mm(np.array([[np.nan, 0.5004]])), [[0, 500]])
    with pytest.raises(ValueError, match='depth images must be'):
        depth_image_to_metres(array_to_image(SAMPLES['rgb8'], 'rgb8', factory=RosbagsFactory()))


def test_image_to_rgb_from_every_colour_encoding():
    from tlessbot_ros.conversions import image_to_rgb

    rgb = SAMPLES['rgb8']
    factory = RosbagsFactory()
    for encoding, array in [('rgb8', rgb), ('bgr8', rgb[:, :, ::-1].copy()),
                            ('rgba8', np.dstack([rgb, np.full(rgb.shape[:2], 255, np.uint8)])),
                            ('bgra8', np.dstack([rgb[:, :, ::-1], np.zeros(rgb.shape[:2],
                                                                           np.uint8)]))]:
        np.testing.assert_array_equal(
            image_to_rgb(array_to_image(array, encoding, factory=factory)), rgb)
    grey = image_to_rgb(array_to_image(SAMPLES['mono8'], 'mono8', factory=factory))
    assert grey.shape == (5, 7, 3) and (grey[:, :, 0] == SAMPLES['mono8']).all()
    with pytest.raises(ValueError, match='colour images'):
        image_to_rgb(array_to_image(SAMPLES['16UC1'], '16UC1', factory=factory))


def test_depth_mm_to_metres_is_float32_times_a_thousandth():
    """Every millimetre value converts as ``float32(v) * float32(0.001)``, bit for bit, with
    0 as NaN (the look-up table stands for that product)."""
    mm = np.arange(65536, dtype=np.uint16).reshape(256, 256)
    depth = depth_image_to_metres(array_to_image(mm, '16UC1', factory=RosbagsFactory()))
    want = mm.astype(np.float32) * np.float32(0.001)
    want[mm == 0] = np.nan
    assert depth.dtype == np.float32 and depth.flags.writeable
    np.testing.assert_array_equal(depth.view(np.uint32), want.view(np.uint32))
