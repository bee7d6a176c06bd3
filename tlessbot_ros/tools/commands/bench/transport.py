"""Transport: camera-sized images between two processes, Fast DDS default against our profile.

    tlessbot bench transport [--fps 30] [--duration 8]
    tlessbot bench transport --two-hosts        # root: also UDP between two network namespaces

One process publishes four image topics (top/side colour 640x480 rgb8 and depth 16UC1, raw
CDR, stamped when sent) at ``--fps``; another subscribes RELIABLE with history depth 2, as the
perception nodes do, and reports what arrived, the latency from the stamp, and its own CPU.
Four set-ups: Fast DDS's built-in transports with deserialised messages, the package profile
(config/fastdds.xml) deserialised, the profile with raw subscriptions, and that with glibc told
to keep freed image buffers (``keep_freed_buffers``; the nodes' way).
Each pair of processes gets its own ROS_DOMAIN_ID offset so set-ups never hear each other.

``--two-hosts`` (root, Linux) compares the nodes' set-up on one host over shared memory with
the publisher and subscriber in two network namespaces joined by a veth pair
(:mod:`~tlessbot_ros.tools.support.netns`), where only UDP crosses: with the package's UDP
profile (config/fastdds_udp.xml, large socket buffers, capped by net.core.rmem_max / wmem_max)
and with that profile's socket buffer sizes removed (the kernel's default buffers: what the
profile gets on a host whose rmem_max / wmem_max were not raised).
"""
from __future__ import annotations

import argparse
import contextlib
import json
import os
import subprocess
import sys
import tempfile
import time
import xml.etree.ElementTree as ElementTree
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tlessbot_ros.conversions.topics import COLOR, DEPTH, camera_topic
from tlessbot_ros.core.common import CAMERA_NAMES

# The cameras' colour and aligned-depth topics: (encoding, bytes per pixel).
TOPICS = {camera_topic(camera, relative): image
          for camera in CAMERA_NAMES
          for relative, image in ((COLOR, ('rgb8', 3)), (DEPTH, ('16UC1', 2)))}


@dataclass(frozen=True)
class Setup:
    """One publisher / subscriber pair. ``profile``: None (Fast DDS built-in transports),
    'package' (config/fastdds.xml), 'udp' (config/fastdds_udp.xml) or 'udp-default-buffers'
    (that without its socket buffer sizes); 'udp*' run across two network namespaces."""

    name: str
    profile: str | None
    raw: bool
    keep_buffers: bool

    @property
    def across_namespaces(self) -> bool:
        return (self.profile or '').startswith('udp')


NODES_SETUP = Setup('package profile, raw, freed buffers kept (the nodes)', 'package', True, True)
SETUPS = (Setup('Fast DDS defaults, deserialised', None, False, False),
          Setup('package profile, deserialised', 'package', False, False),
          Setup('package profile, raw', 'package', True, False),
          NODES_SETUP)
TWO_HOST_SETUPS = (
    Setup('one host, shared memory (the nodes, config/fastdds.xml)', 'package', True, True),
    Setup('two namespaces, UDP, kernel default socket buffers', 'udp-default-buffers', True,
          True),
    Setup('two namespaces, UDP, config/fastdds_udp.xml', 'udp', True, True))
BUFFER_SIZE_TAGS = ('sendBufferSize', 'receiveBufferSize')


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('--fps', type=float, default=30.0)
    parser.add_argument('--duration', type=float, default=8.0, help='seconds of publishing')
    parser.add_argument('--two-hosts', action='store_true',
                        help='compare shared memory on one host with UDP between two network '
                             'namespaces (needs root and iproute2; see docs/two-hosts.md)')
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
           keep_buffers: bool, prefix: list[str]) -> subprocess.Popen:
    command = [*prefix, sys.executable, '-m', 'tlessbot_ros.tools.cli', 'bench', 'transport',
               '--role', role, '--fps', str(fps), '--duration', str(duration_s)]
    command += (['--raw'] if raw else []) + (['--keep-buffers'] if keep_buffers else [])
    return subprocess.Popen(command, env=env, stdout=subprocess.PIPE, text=True)


def _last_json(process: subprocess.Popen) -> dict:
    out, _ = process.communicate(timeout=120)
    lines = [line for line in out.splitlines() if line.startswith('{')]
    return json.loads(lines[-1]) if lines else {}


def without_buffer_sizes(profile: Path, out: Path) -> Path:
    """Write ``profile`` without its transports' socket buffer sizes to ``out``."""
    tree = ElementTree.parse(profile)
    namespace = tree.getroot().tag.partition('}')[0] + '}'
    ElementTree.register_namespace('', namespace.strip('{}'))
    for descriptor in tree.getroot().iter(f'{namespace}transport_descriptor'):
        for tag in BUFFER_SIZE_TAGS:
            for element in descriptor.findall(f'{namespace}{tag}'):
                descriptor.remove(element)
    tree.write(out, encoding='UTF-8', xml_declaration=True)
    return out


def kernel_socket_buffer_max() -> str:
    """net.core.rmem_max / wmem_max of this host, for the report."""
    values = []
    for name in ('rmem_max', 'wmem_max'):
        try:
            values.append(f'{name} {int(Path(f"/proc/sys/net/core/{name}").read_text()):,}')
        except (OSError, ValueError):
            values.append(f'{name} unknown')
    return 'net.core.' + ', '.join(values) + ' bytes'


def _environments(setup: Setup, base: dict[str, str], namespaces, scratch: Path):
    """(env, publisher prefix, subscriber prefix) of a set-up."""
    from tlessbot_ros.io.config import package_path
    from tlessbot_ros.nodes.common import use_package_dds_profile
    from tlessbot_ros.tools.support.netns import UDP_PROFILE_NAME, udp_environ

    if not setup.across_namespaces:
        env = dict(base)
        if setup.profile == 'package':   # else no profile variable: built-in transports
            use_package_dds_profile(env)
        return env, [], []
    publisher_ns, subscriber_ns = namespaces
    profile = package_path('config', UDP_PROFILE_NAME)
    if setup.profile == 'udp-default-buffers':
        profile = without_buffer_sizes(profile, scratch / 'udp_default_buffers.xml')
    env = udp_environ(base, [publisher_ns.address, subscriber_ns.address], profile=str(profile))
    return env, publisher_ns.exec_prefix(), subscriber_ns.exec_prefix()


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
    from tlessbot_ros.nodes.common import DDS_PROFILE_VARIABLES
    from tlessbot_ros.tools.support.netns import two_namespaces

    base = {k: v for k, v in os.environ.items() if k not in DDS_PROFILE_VARIABLES}
    base.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    domain = int(base.get('ROS_DOMAIN_ID', '0'))
    setups = TWO_HOST_SETUPS if args.two_hosts else SETUPS
    rows = []
    with contextlib.ExitStack() as stack:
        scratch = Path(stack.enter_context(tempfile.TemporaryDirectory()))
        namespaces = stack.enter_context(two_namespaces('tlessbot-transport')) \
            if args.two_hosts else None
        for k, setup in enumerate(setups):
            env, publisher_prefix, subscriber_prefix = _environments(
                setup, dict(base, ROS_DOMAIN_ID=str((domain + 11 + k) % 100)), namespaces,
                scratch)
            children = {role: _child(role, fps=args.fps, duration_s=args.duration, env=env,
                                     raw=setup.raw, keep_buffers=setup.keep_buffers,
                                     prefix=prefix)
                        for role, prefix in (('subscriber', subscriber_prefix),
                                             ('publisher', publisher_prefix))}
            sent = _last_json(children['publisher']).get('published', 0)
            rows.append(_row(setup.name, sent, _last_json(children['subscriber'])))
    print('| set-up | images delivered | latency p50 / p95 | subscriber CPU (one core) |')
    print('|---|---|---|---|')
    print('\n'.join(rows))
    print(f'\n4 topics (2 x 0.9 MiB rgb8 + 2 x 0.6 MiB 16UC1) at {args.fps:.0f} fps for '
          f'{args.duration:.0f} s; RELIABLE, history depth 2; {os.cpu_count()} cores.')
    if args.two_hosts:
        print(f"{kernel_socket_buffer_max()}: the cap on the UDP profile's socket buffers.")
    return 0


def _row(name: str, sent: int, got: dict) -> str:
    counts = got.get('received', {})
    share = 100.0 * sum(counts.values()) / max(1, sent * len(TOPICS))
    p50, p95 = got.get('p50_ms'), got.get('p95_ms')
    return (f'| {name} | {share:.0f} % | '
            f'{"n/a" if p50 is None else f"{p50:.1f} / {p95:.1f} ms"} | '
            f'{100 * got.get("cpu", float("nan")):.0f} % |')
