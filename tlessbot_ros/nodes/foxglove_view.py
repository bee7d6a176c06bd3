"""foxglove_view: a live view of the graph for the Foxglove app (off unless launched).

Subscribes (every ``scan_period_s``, to the topics that match ``topics`` as they appear; each
message's CDR bytes forwarded unchanged):
    /objects/detections, /objects/<part>/pose, /objects/markers, /objects/debug_image, /tf,
    /tf_static (TRANSIENT_LOCAL: the last one is there for a late subscriber)
Serves: a Foxglove WebSocket on ``host``:``port`` (127.0.0.1:8765), one channel per topic with
its ``ros2msg`` schema and ``cdr`` encoding, so the app shows them as the ROS messages they are.
Parameters (read-only): ``host`` (127.0.0.1: this PC only; 0.0.0.0 opens it to the network),
``port`` (0: any free port), ``topics`` (fnmatch patterns), ``scan_period_s``.
"""
from __future__ import annotations

import fnmatch
import time
from functools import partial
from typing import Any

from rclpy.node import Node
from rclpy.qos import (
    DurabilityPolicy,
    HistoryPolicy,
    QoSProfile,
    ReliabilityPolicy,
    qos_profile_sensor_data,
)

from tlessbot_ros.conversions.schemas import message_definition
from tlessbot_ros.conversions.topics import DEBUG_IMAGE, DETECTIONS, MARKERS, TF, TF_STATIC
from tlessbot_ros.errors import TlessbotError
from tlessbot_ros.nodes.common import message_class, run_node
from tlessbot_ros.nodes.parameters import LiveParameters

TOPICS = [DETECTIONS, '/objects/*/pose', MARKERS, DEBUG_IMAGE, TF, TF_STATIC]
LATCHED = QoSProfile(reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL,
                     history=HistoryPolicy.KEEP_LAST, depth=1)


class FoxgloveViewNode(Node):
    """ROS topics -> Foxglove WebSocket channels, bytes unchanged."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__('foxglove_view', **kwargs)
        parameters = LiveParameters(self)
        host = parameters.read_only('host', '127.0.0.1', (
            'address the WebSocket listens on: 127.0.0.1 (this PC only) or 0.0.0.0 (network)'))
        port = parameters.read_only('port', 8765, 'WebSocket port (0: any free port)')
        self.patterns = list(parameters.read_only('topics', TOPICS, (
            'topics forwarded (fnmatch patterns), found as they appear')))
        period = parameters.read_only('scan_period_s', 1.0,
                                      'how often new topics are looked for, s (> 0)')
        try:
            import foxglove
        except ImportError:
            raise TlessbotError('foxglove-sdk is not installed: pip install foxglove-sdk') \
                from None
        self._foxglove = foxglove
        try:
            self.server = foxglove.start_server(name='tlessbot', host=host, port=int(port))
        except Exception as error:   # the SDK raises its own error types
            raise TlessbotError(f'cannot serve Foxglove on {host}:{port}: {error}') from None
        self.channels: dict[str, Any] = {}
        self._skipped: set[str] = set()
        self.get_logger().info(f'Foxglove live view on ws://{host}:{self.server.port}')
        self.create_timer(float(period), self._scan)
        self._scan()

    def _scan(self) -> None:
        """Forward every wanted topic that appeared since the last scan."""
        for topic, types in self.get_topic_names_and_types():
            if topic in self.channels or topic in self._skipped or not any(
                    fnmatch.fnmatchcase(topic, p) for p in self.patterns):
                continue
            msgtype = types[0]
            try:
                schema = message_definition(msgtype)
                cls = message_class(msgtype)
            except ValueError as error:
                self._skipped.add(topic)
                self.get_logger().warning(f'{topic} not forwarded: {error}')
                continue
            channel = self._foxglove.Channel(
                topic, message_encoding='cdr', schema=self._foxglove.Schema(
                    name=msgtype, encoding='ros2msg', data=schema.encode()))
            self.channels[topic] = channel
            qos = LATCHED if topic == TF_STATIC else qos_profile_sensor_data
            self.create_subscription(cls, topic, partial(self._forward, channel), qos,
                                     raw=True)
            self.get_logger().info(f'forwarding {topic} ({msgtype})')

    def _forward(self, channel: Any, data: bytes) -> None:
        channel.log(data, log_time=time.time_ns())

    def destroy_node(self) -> None:
        self.server.stop()
        super().destroy_node()


def main(args: list[str] | None = None) -> None:
    run_node(FoxgloveViewNode, args)


if __name__ == '__main__':
    main()
