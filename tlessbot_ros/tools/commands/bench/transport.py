"""Transport: camera-sized images between two processes, Fast DDS default against our profile.

    tlessbot bench transport [--fps 30] [--duration 8]

One process publishes four image topics (top/side colour 640x480 rgb8 and depth 16UC1, raw
CDR, stamped when sent) at ``--fps``; another subscribes RELIABLE with history depth 2, as the
perception nodes do, and reports what arrived, the latency from the stamp, and its own CPU.
Four set-ups: Fast DDS's built-in transports with deserialised messages, the package profile
(config/fastdds.xml) deserialised, the profile with raw subscriptions, and that with glibc told
to keep freed image buffers (``keep_freed_buffers``; the nodes' way).
Each pair of processes gets its own ROS_DOMAIN_ID offset so set-ups never hear each other.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time

import numpy as np

from tlessbot_ros.conversions.topics import COLOR, DEPTH, camera_topic
from tlessbot_ros.core.common import CAMERA_NAMES

# The cameras' colour and aligned-depth topics: (encoding, bytes per pixel).
TOPICS = {camera_topic(camera, relative): image
          for camera in CAMERA_NAMES
          for relative, image in ((COLOR, ('rgb8', 3)), (DEPTH, ('16UC1', 2)))}
SETUPS = (('Fast DDS defaults, deserialised', False, False, False),
          ('package profile, deserialised', True, False, False),
          ('package profile, raw', True, True, False),
          ('package profile, raw, freed buffers kept (the nodes)', True, True, True))


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('--fps', type=float, default=30.0)
    parser.add_argument('--duration', type=float, default=8.0, help='seconds of publishing')
    parser.add_argument('--role', choices=('publisher', 'subscriber'), help=argparse.SUPPRESS)
    parser.add_argument('--raw', action='store_true', help=argparse.SUPPRESS)
    parser.add_argument('--keep-buffers', action='store_true', help=argparse.SUPPRESS)


def _publisher(*, fps: float, duration_s: float) -> None:
    import rclpy
    from rclpy.serialization import serialize_message
    from sensor_msgs.msg import Image

    from tlessbot_ros.conversions.cdr import restamp_cdr
    from tlessbot_ros.nodes.common import RESULT_QOS

    rclpy.init()
    node = rclpy.create_node('transport_publisher')
    messages = {}
    for topic, (encoding, bytes_per_pixel) in TOPICS.items():
        msg = Image(height=480, width=640, encoding=encoding, step=640 * bytes_per_pixel)
        msg.data = bytes(480 * 640 * bytes_per_pixel)
        messages[topic] = (node.create_publisher(Image, topic, RESULT_QOS),
                           serialize_message(msg))
    time.sleep(2.0)  # discovery
    start = time.monotonic()
    frames = int(duration_s * fps)
    for k in range(frames):
        delay = start + k / fps - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        now = node.get_clock().now().nanoseconds
        for publisher, raw in messages.values():
            publisher.publish(restamp_cdr(raw, now))
    print(json.dumps({'published': frames}))
    node.destroy_node()
    rclpy.try_shutdown()


def _subscriber(*, duration_s: float, raw: bool) -> None:
    import rclpy
    from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import Image

    from tlessbot_ros.conversions.cdr import header_stamp_ns
    from tlessbot_ros.conversions.messages import stamp_to_ns

    rclpy.init()
    node = rclpy.create_node('transport_subscriber')
    qos = QoSProfile(reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST,
                     depth=2)
    latencies: list[float] = []
    received = dict.fromkeys(TOPICS, 0)

    def on_message(topic: str):
        def callback(msg) -> None:
            stamp = header_stamp_ns(msg) if raw else stamp_to_ns(msg.header.stamp)
            latencies.append((node.get_clock().now().nanoseconds - stamp) / 1e6)
            received[topic] += 1
        return callback

    for topic in TOPICS:
        node.create_subscription(Image, topic, on_message(topic), qos, raw=raw)
    deadline = time.monotonic() + duration_s + 4.0
    cpu_start, cpu_from = None, time.monotonic() + 3.0   # CPU while frames flow
    while time.monotonic() < deadline:
        rclpy.spin_once(node, timeout_sec=0.05)
        if cpu_start is None and time.monotonic() >= cpu_from:
            cpu_start, wall_start = time.process_time(), time.monotonic()
    cpu = (time.process_time() - cpu_start) / max(time.monotonic() - wall_start, 1e-9)
    print(json.dumps({'received': received, 'cpu': cpu,
                      'p50_ms': float(np.percentile(latencies, 50)) if latencies else None,
                      'p95_ms': float(np.percentile(latencies, 95)) if latencies else None}))
    node.destroy_node()
    rclpy.try_shutdown()


def _child(role: str, *, fps: float, duration_s: float, env: dict[str, str], raw: bool,
           keep_buffers: bool) -> subprocess.Popen:
    command = [sys.executable, '-m', 'tlessbot_ros.tools.cli', 'bench', 'transport',
               '--role', role, '--fps', str(fps), '--duration', str(duration_s)]
    command += (['--raw'] if raw else []) + (['--keep-buffers'] if keep_buffers else [])
    return subprocess.Popen(command, env=env, stdout=subprocess.PIPE, text=True)


def _last_json(process: subprocess.Popen) -> dict:
    out, _ = process.communicate(timeout=120)
    lines = [line for line in out.splitlines() if line.startswith('{')]
    return json.loads(lines[-1]) if lines else {}


def run(args: argparse.Namespace) -> int:
    if args.keep_buffers:
        from tlessbot_ros.nodes.common import keep_freed_buffers
        keep_freed_buffers()
    if args.role == 'publisher':
        _publisher(fps=args.fps, duration_s=args.duration)
        return 0
    if args.role == 'subscriber':
        _subscriber(duration_s=args.duration, raw=args.raw)
        return 0
    from tlessbot_ros.nodes.common import DDS_PROFILE_VARIABLES, use_package_dds_profile

    base = {k: v for k, v in os.environ.items() if k not in DDS_PROFILE_VARIABLES}
    domain = int(base.get('ROS_DOMAIN_ID', '0'))
    rows = []
    for k, (name, with_profile, raw, keep_buffers) in enumerate(SETUPS):
        env = dict(base, ROS_DOMAIN_ID=str((domain + 11 + k) % 100),
                   ROS_AUTOMATIC_DISCOVERY_RANGE=base.get('ROS_AUTOMATIC_DISCOVERY_RANGE',
                                                          'LOCALHOST'))
        if with_profile:   # else no profile variable: Fast DDS's built-in transports
            use_package_dds_profile(env)
        subscriber = _child('subscriber', fps=args.fps, duration_s=args.duration, env=env,
                            raw=raw, keep_buffers=keep_buffers)
        publisher = _child('publisher', fps=args.fps, duration_s=args.duration, env=env,
                           raw=raw, keep_buffers=keep_buffers)
        sent = _last_json(publisher).get('published', 0)
        got = _last_json(subscriber)
        counts = got.get('received', {})
        share = 100.0 * sum(counts.values()) / max(1, sent * len(TOPICS))
        p50, p95 = got.get('p50_ms'), got.get('p95_ms')
        rows.append(f'| {name} | {share:.0f} % | '
                    f'{"n/a" if p50 is None else f"{p50:.1f} / {p95:.1f} ms"} | '
                    f'{100 * got.get("cpu", float("nan")):.0f} % |')
    print('| set-up | images delivered | latency p50 / p95 | subscriber CPU (one core) |')
    print('|---|---|---|---|')
    print('\n'.join(rows))
    print(f'\n4 topics (2 x 0.9 MiB rgb8 + 2 x 0.6 MiB 16UC1) at {args.fps:.0f} fps for '
          f'{args.duration:.0f} s; RELIABLE, history depth 2; {os.cpu_count()} cores.')
    return 0
