"""sensor_msgs/PointCloud2 <-> (N, 3) xyz and (N, 3) uint8 colour.

Written clouds use the realsense-ros layout: x, y, z FLOAT32 at offsets 0, 4, 8, then ``rgb`` as a
packed FLOAT32 at offset 16 (bytes B, G, R, 0), point_step 20, unordered (height 1), dense.
Read clouds may have any layout: fields are found by name and offset; points with a NaN
coordinate are skipped.
"""
from __future__ import annotations

from typing import Any, Literal, cast

import numpy as np

from tlessbot_ros.conversions.camera_info import camera_info_to_intrinsics
from tlessbot_ros.conversions.image import depth_image_to_metres
from tlessbot_ros.conversions.messages import (
    MessageFactory,
    default_factory,
    make_header,
    message_bytes,
    stamp_to_ns,
)
from tlessbot_ros.core.common import depth_to_points

# sensor_msgs/PointField datatype constants -> numpy dtype
POINT_FIELD_DTYPES = {1: np.int8, 2: np.uint8, 3: np.int16, 4: np.uint16, 5: np.int32,
                      6: np.uint32, 7: np.float32, 8: np.float64}
FLOAT32 = 7


def pointcloud2_to_xyz(msg: Any) -> tuple[np.ndarray, np.ndarray | None]:
    """Decode a PointCloud2.

    Returns:
        xyz: (N, 3) float32 metres of the points whose x, y and z are all finite.
        rgb: (N, 3) uint8 (R, G, B) when the cloud has an ``rgb`` or ``rgba`` field, else None.

    Raises:
        ValueError: a missing x/y/z field, an unsupported datatype, or a data length that does
            not match ``row_step * height``.
    """
    fields = {f.name: f for f in msg.fields}
    missing = [name for name in ('x', 'y', 'z') if name not in fields]
    if missing:
        raise ValueError(f'PointCloud2 lacks field(s) {missing}; has {sorted(fields)}')
    height, width = int(msg.height), int(msg.width)
    point_step, row_step = int(msg.point_step), int(msg.row_step)
    count = height * width
    buffer = message_bytes(msg.data)
    if buffer.size != row_step * height:
        raise ValueError(f'PointCloud2 data has {buffer.size} bytes, expected row_step*height'
                         f' = {row_step}*{height} = {row_step * height}')
    if count == 0:
        return np.zeros((0, 3), np.float32), (np.zeros((0, 3), np.uint8)
                                               if _colour_field(fields) else None)
    if point_step * width > row_step:
        raise ValueError(f'point_step*width = {point_step * width} exceeds row_step {row_step}')
    rows = buffer.reshape(height, row_step)[:, :point_step * width]
    points = np.ascontiguousarray(rows).reshape(count, point_step)
    byte_order: Literal['>', '<'] = '>' if msg.is_bigendian else '<'

    def column(name: str) -> np.ndarray:
        field = fields[name]
        if field.datatype not in POINT_FIELD_DTYPES:
            raise ValueError(f'field {name!r} has unsupported datatype {field.datatype}')
        dtype = np.dtype(POINT_FIELD_DTYPES[field.datatype]).newbyteorder(byte_order)
        offset = int(field.offset)
        if offset + dtype.itemsize > point_step:
            raise ValueError(f'field {name!r} at offset {offset} overruns point_step {point_step}')
        return cast(np.ndarray, points[:, offset:offset + dtype.itemsize].copy().view(dtype)[:, 0])

    xyz = np.stack([column(n).astype(np.float32) for n in ('x', 'y', 'z')], axis=1)
    finite = np.isfinite(xyz).all(axis=1)
    rgb = None
    colour_name = _colour_field(fields)
    if colour_name is not None:
        offset = int(fields[colour_name].offset)
        packed = points[:, offset:offset + 4]
        # Packed as a little-endian uint32 0x00RRGGBB: bytes in memory are B, G, R, A.
        bgr = packed[:, 2::-1] if byte_order == '<' else packed[:, 1:4]
        rgb = np.ascontiguousarray(bgr[finite])
    return xyz[finite], rgb


def _colour_field(fields: dict[str, Any]) -> str | None:
    for name in ('rgb', 'rgba'):
        if name in fields:
            return name
    return None


def xyz_to_pointcloud2(
    xyz: np.ndarray,
    rgb: np.ndarray | None = None,
    *,
    frame_id: str = '',
    stamp_ns: int = 0,
    factory: MessageFactory | None = None,
) -> Any:
    """Encode (N, 3) xyz metres (+ optional (N, 3) uint8 RGB) as a realsense-ros PointCloud2."""
    xyz = np.asarray(xyz)
    if xyz.ndim != 2 or xyz.shape[1] != 3:
        raise ValueError(f'xyz must be (N, 3), got shape {xyz.shape}')
    count = xyz.shape[0]
    point_step = 20 if rgb is not None else 16
    record = np.zeros((count, point_step), dtype=np.uint8)
    record[:, :12] = np.ascontiguousarray(xyz, dtype='<f4').view(np.uint8).reshape(count, 12)
    factory = factory or default_factory()
    fields = [factory.new('sensor_msgs/msg/PointField', name=name, offset=4 * i,
                          datatype=FLOAT32, count=1) for i, name in enumerate('xyz')]
    if rgb is not None:
        rgb = np.asarray(rgb)
        if rgb.shape != (count, 3) or rgb.dtype != np.uint8:
            raise ValueError(f'rgb must be (N, 3) uint8 matching xyz, got {rgb.shape} {rgb.dtype}')
        record[:, 16:19] = rgb[:, ::-1]  # B, G, R, 0
        fields.append(factory.new('sensor_msgs/msg/PointField', name='rgb', offset=16,
                                  datatype=FLOAT32, count=1))
    return factory.new(
        'sensor_msgs/msg/PointCloud2',
        header=make_header(frame_id, stamp_ns, factory),
        height=1,
        width=count,
        fields=fields,
        is_bigendian=False,
        point_step=point_step,
        row_step=point_step * count,
        data=factory.uint8_array(record),
        is_dense=True,
    )


def depth_image_to_pointcloud2(
    depth_msg: Any,
    info_msg: Any,
    color: np.ndarray | None = None,
    *,
    factory: MessageFactory | None = None,
) -> Any:
    """Cloud of the valid pixels of an aligned depth image, in the depth image's frame and stamp.

    Args:
        depth_msg: 16UC1 (mm) or 32FC1 (m) depth Image.
        info_msg: the CameraInfo of that depth image.
        color: optional (H, W, 3) uint8 RGB image aligned with the depth, for the rgb field.
    """
    depth = depth_image_to_metres(depth_msg)
    intrinsics = camera_info_to_intrinsics(info_msg)
    if depth.shape != (intrinsics.height, intrinsics.width):
        raise ValueError(f'depth is {depth.shape[1]}x{depth.shape[0]} but CameraInfo says '
                         f'{intrinsics.width}x{intrinsics.height}')
    xyz, pixels = depth_to_points(depth, intrinsics.K)
    rgb = None
    if color is not None:
        if color.shape[:2] != depth.shape:
            raise ValueError(f'colour {color.shape[:2]} and depth {depth.shape} sizes differ')
        rgb = color[pixels[:, 0], pixels[:, 1]]
    return xyz_to_pointcloud2(xyz, rgb, frame_id=depth_msg.header.frame_id,
                              stamp_ns=stamp_to_ns(depth_msg.header.stamp), factory=factory)
