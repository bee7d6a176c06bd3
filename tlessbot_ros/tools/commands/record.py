"""Record topics from the ROS graph into a rosbag2 bag (mcap by default) without ros2 bag.

    tlessbot record --out run1 /objects/obj_05/pose /side/color/image_raw --duration 10
"""
from __future__ import annotations

import argparse
import time
from collections.abc import Callable
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING

from tlessbot_ros.errors import BagError

if TYPE_CHECKING:
    from tlessbot_ros.io.bag_writer import BagWriter


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('topics', nargs='+', help='topics to record')
    parser.add_argument('--out', required=True, help='output bag folder (must not exist)')
    parser.add_argument('--storage', choices=('mcap', 'sqlite3'), default='mcap')
    parser.add_argument('--duration', type=float, default=0.0, metavar='S',
                        help='stop after S seconds (default: until Ctrl-C)')
    parser.add_argument('--discovery-timeout', type=float, default=5.0, metavar='S',
                        help='how long to wait for the topics to appear in the graph')


def run(args: argparse.Namespace) -> int:
    counts = record(args.topics, Path(args.out), storage=args.storage, duration_s=args.duration,
                    discovery_timeout_s=args.discovery_timeout)
    print('recorded ' + ', '.join(f'{t}: {n}' for t, n in counts.items()) + f' into {args.out}')
    return 0


def record(topics: list[str], out: Path, *, storage: str = 'mcap', duration_s: float = 0.0,
           discovery_timeout_s: float = 5.0, until: Callable[[], bool] | None = None,
           on_message: Callable[[str, bytes], None] | None = None) -> dict[str, int]:
    """Record ``topics`` into the new bag folder ``out`` until ``duration_s`` (0: no limit)
    has passed, ``until()`` says so, or Ctrl-C; ``on_message(topic, raw)`` sees every message
    written. Returns the message count per topic.

    Raises:
        BagError: ``out`` exists, or a topic is not in the graph within the discovery time.
    """
    import rclpy
    from rclpy.executors import ExternalShutdownException

    from tlessbot_ros.io.bag_writer import BagWriter, offered_qos
    from tlessbot_ros.nodes.common import (
        SENSOR_QOS,
        init_ros,
        interrupts_deferred,
        message_class,
        raise_if_interrupted,
        spin_once_or_interrupt,
    )

    if out.exists():
        raise BagError(f'output {out} exists; choose a new folder')
    topics = [t if t.startswith('/') else '/' + t for t in topics]
    init_ros()
    node = rclpy.create_node('tlessbot_record')
    writer = None
    counts = dict.fromkeys(topics, 0)
    try:
        deadline = time.monotonic() + discovery_timeout_s
        types: dict[str, str] = {}
        while len(types) < len(topics) and time.monotonic() < deadline:
            graph = dict(node.get_topic_names_and_types())
            types = {t: graph[t][0] for t in topics if graph.get(t)}
            spin_once_or_interrupt(partial(rclpy.spin_once, node, timeout_sec=0.1))
        missing = sorted(set(topics) - set(types))
        if missing:
            raise BagError(f'topic(s) {missing} not found in the ROS graph')
        with interrupts_deferred():   # Ctrl-C here would leave half a schema or channel
            writer = BagWriter(out, storage=storage)
            writer.open()
            for topic, msgtype in types.items():
                # What the publishers offer, so that a replay offers it again (as ros2 bag does).
                writer.add_topic(topic, msgtype, [offered_qos(info.qos_profile) for info
                                                  in node.get_publishers_info_by_topic(topic)])
        raise_if_interrupted()

        for topic, msgtype in types.items():
            node.create_subscription(message_class(msgtype), topic,
                                     message_recorder(writer, topic, counts, on_message),
                                     SENSOR_QOS, raw=True)
        print(f'recording {len(types)} topic(s) into {out}'
              + (f' for {duration_s:g} s' if duration_s > 0 else '; Ctrl-C stops'),
              flush=True)
        stop = time.monotonic() + duration_s if duration_s > 0 else None
        while rclpy.ok() and (stop is None or time.monotonic() < stop) and \
                not (until is not None and until()):
            spin_once_or_interrupt(partial(rclpy.spin_once, node, timeout_sec=0.1))
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        if writer is not None:
            writer.close()
        node.destroy_node()
        rclpy.try_shutdown()
    return counts


def message_recorder(writer: BagWriter, topic: str, counts: dict[str, int],
                     on_message: Callable[[str, bytes], None] | None = None
                     ) -> Callable[[bytes], None]:
    """The subscription callback that appends ``topic``'s serialized messages to ``writer``,
    stamped with the time of arrival, and counts them in ``counts`` (then calls
    ``on_message(topic, raw)``); prints the first of each topic. A message is written whole
    or not at all: Ctrl-C inside the write is deferred to the end of the turn."""
    from tlessbot_ros.nodes.common import interrupts_deferred

    def on_raw(raw: bytes) -> None:
        with interrupts_deferred():
            writer.write(topic, time.time_ns(), raw)
            counts[topic] += 1
            if counts[topic] == 1:   # data flows: what a user (or a test) waits for
                print(f'first message on {topic}', flush=True)
            if on_message is not None:
                on_message(topic, raw)
    return on_raw
