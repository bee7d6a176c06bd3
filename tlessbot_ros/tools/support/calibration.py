"""The rig estimated from a bag's depth frames, and its report (``tlessbot calibrate``)."""
from __future__ import annotations

import time
from collections import deque
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from tlessbot_ros.core.calibrate import (
    RigErrors,
    RigEstimate,
    SceneCalibrationParams,
    SceneCalibrator,
    rig_errors,
)
from tlessbot_ros.core.common import CAMERA_NAMES, Rig, StampSynchroniser
from tlessbot_ros.errors import BagError, TlessbotError


@dataclass
class BagFrame:
    """One two-view frame of a bag: per camera, (H, W) float32 depth in metres, the (3, 3)
    camera matrix and, when asked for, (H, W, 3) uint8 RGB."""

    stamp_ns: int
    depth: dict[str, np.ndarray]
    K: dict[str, np.ndarray]
    rgb: dict[str, np.ndarray] = field(default_factory=dict)


def bag_frames(bag: str | Path, *, cameras: Sequence[str] = CAMERA_NAMES,
               colour: bool = False, max_age_s: float = 0.05) -> Iterator[BagFrame]:
    """The two-view frames of a bag, in order.

    Each camera's aligned depth is paired with its aligned-depth camera_info (and colour) by
    header stamp, and the cameras with each other within ``max_age_s`` (as the nodes pair
    them).

    Raises:
        BagError: the bag is missing, unreadable, or lacks the topics.
    """
    from tlessbot_ros.conversions import (
        camera_info_to_intrinsics,
        depth_image_to_metres,
        image_to_rgb,
    )
    from tlessbot_ros.conversions.cdr import header_stamp_ns
    from tlessbot_ros.conversions.topics import COLOR, DEPTH, DEPTH_INFO, camera_topic
    from tlessbot_ros.io.bags import deserialize, read_bag

    kinds = (DEPTH, DEPTH_INFO, COLOR) if colour else (DEPTH, DEPTH_INFO)
    streams = {camera_topic(c, t): (c, t) for c in cameras for t in kinds}
    pairing = StampSynchroniser(list(streams), slop_ns=int(max_age_s * 1e9), queue_size=30)
    for message in read_bag(bag, list(streams)):
        try:
            stamp = header_stamp_ns(message.raw)
        except ValueError as error:
            raise BagError(f'{message.topic}: {error}') from None
        found = pairing.add(message.topic, stamp, message)
        if found is None:
            continue
        frame = BagFrame(header_stamp_ns(found[camera_topic(cameras[0], DEPTH)].raw), {}, {})
        for topic, raw in found.items():
            camera, kind = streams[topic]
            msg = deserialize(raw)
            if kind == DEPTH:
                frame.depth[camera] = depth_image_to_metres(msg)
            elif kind == COLOR:
                frame.rgb[camera] = image_to_rgb(msg)
            else:
                frame.K[camera] = np.asarray(camera_info_to_intrinsics(msg).K, np.float64)
        yield frame


def live_frames(*, cameras: Sequence[str] = CAMERA_NAMES, timeout_s: float = 120.0,
                max_age_s: float = 0.05) -> Iterator[BagFrame]:
    """Two-view depth frames from the cameras' topics (``/top/aligned_depth_to_color/...``),
    paired as :func:`bag_frames` pairs a bag's, until ``timeout_s`` seconds have passed or
    the consumer stops. Subscribes best effort (it hears reliable publishers too) and keeps
    only the newest frames: frames are dropped, never queued, while a slow consumer works.

    Raises:
        TlessbotError: no frame came within ``timeout_s``.
    """
    import rclpy

    from tlessbot_ros.conversions import camera_info_to_intrinsics, depth_image_to_metres
    from tlessbot_ros.conversions.messages import stamp_to_ns
    from tlessbot_ros.conversions.topics import DEPTH, DEPTH_INFO, camera_topic
    from tlessbot_ros.nodes.common import (
        SENSOR_QOS,
        init_ros,
        message_class,
        raise_if_interrupted,
    )

    types = {DEPTH: 'sensor_msgs/msg/Image', DEPTH_INFO: 'sensor_msgs/msg/CameraInfo'}
    streams = {camera_topic(c, t): (c, t) for c in cameras for t in types}
    pairing = StampSynchroniser(list(streams), slop_ns=int(max_age_s * 1e9), queue_size=30)
    ready: deque[dict] = deque(maxlen=2)
    init_ros()
    node = rclpy.create_node('tlessbot_calibrate')
    try:
        for topic, (_, kind) in streams.items():
            def take(msg: object, topic: str = topic) -> None:
                found = pairing.add(topic, stamp_to_ns(msg.header.stamp), msg)
                if found is not None:
                    ready.append(found)
            node.create_subscription(message_class(types[kind]), topic, take, SENSOR_QOS)
        deadline = time.monotonic() + timeout_s
        got = 0
        while time.monotonic() < deadline:
            rclpy.spin_once(node, timeout_sec=0.1)
            raise_if_interrupted()
            while ready:
                found = ready.popleft()
                frame = BagFrame(stamp_to_ns(found[camera_topic(cameras[0], DEPTH)].header.stamp),
                                 {}, {})
                for topic, msg in found.items():
                    camera, kind = streams[topic]
                    if kind == DEPTH:
                        frame.depth[camera] = depth_image_to_metres(msg)
                    else:
                        frame.K[camera] = np.asarray(camera_info_to_intrinsics(msg).K,
                                                     np.float64)
                got += 1
                yield frame
        if not got:
            raise TlessbotError(f'no two-view depth frame on {sorted(streams)} within '
                                f'{timeout_s:g} s: are both cameras running?')
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


def calibrate_from_frames(frames: Iterable[BagFrame], prior: Rig, *,
                          params: SceneCalibrationParams = SceneCalibrationParams(),
                          every: int = 1) -> tuple[RigEstimate | None, int]:
    """Run the scene estimator over ``frames`` (every ``every``-th) and solve once.

    Returns:
        the estimate (None when no frame showed both tables) and the frames read.
    """
    calibrator = SceneCalibrator(prior, params=params)
    read = 0
    for index, frame in enumerate(frames):
        read += 1
        if index % every == 0:
            calibrator.add_frame(frame.depth, K=frame.K)
    return calibrator.solve(), read


def format_report(estimate: RigEstimate, *, frames_read: int, config: str) -> str:
    """The lines ``tlessbot calibrate`` prints: what the estimate rests on, how far the
    configured rig is from it, per camera and top -> side."""
    e = estimate
    lines = [f'frames: {frames_read} read, {e.planes} with the table in both views, '
             f'{e.frames} with parts in both views, {e.frames_matched} with parts matched '
             f'between the views ({e.matches} matches)']
    if e.in_plane_solved:
        lines.append(f'fit: residual {1e3 * e.residual_m:.2f} mm over {e.pairs} point pairs, '
                     f'overlap {e.overlap:.2f} (with the configured placement: '
                     f'{e.prior_overlap:.2f}), spread of the per-frame fits '
                     f'{e.yaw_sigma_deg:.3f} deg / {1e3 * e.shift_sigma_m:.2f} mm: '
                     + ('confident' if e.confident else 'NOT confident'))
    else:
        lines.append('fit: no part seen by both views: only the table planes were used '
                     '(the side camera keeps its configured place on the table)')
    lines.append(f'difference from {config} (the top camera keeps its configured heading and '
                 'place on the table: the scene cannot tell them):')
    for name, d in e.differences.items():
        label = 'top -> side' if name == 'top_side' else name
        lines.append(f'  {label:<12} {d.angle_deg:7.3f} deg {1e3 * d.offset_m:8.2f} mm')
    yaw, x, y = e.in_plane
    lines.append(f'in-plane correction of the side camera: turn {yaw:+.3f} deg, shift '
                 f'({1e3 * x:+.2f}, {1e3 * y:+.2f}) mm')
    return '\n'.join(lines)


def format_errors(truth: Rig, estimate: Rig, prior: Rig, *, truth_name: str = 'the truth') -> str:
    """Gauge-free errors of the estimated and the configured rig against the true one: the
    top -> side transform, each camera's height and tilt over the table."""
    got, before = rig_errors(truth, estimate), rig_errors(truth, prior)

    def relative(errors: RigErrors) -> str:
        return f'{errors.relative.angle_deg:7.3f} deg {1e3 * errors.relative.offset_m:7.2f} mm'

    def camera(errors: RigErrors, name: str) -> str:
        return f'{1e3 * errors.height_m[name]:+7.2f} mm, tilt {errors.tilt_deg[name]:6.3f} deg'

    lines = [f'errors against {truth_name} (estimate | config):',
             f'  top -> side    {relative(got)} | {relative(before)}']
    lines += [f'  {name:<6} height {camera(got, name)} | {camera(before, name)}'
              for name in got.height_m]
    return '\n'.join(lines)
