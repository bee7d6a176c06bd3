"""Publish a rosbag2 bag (mcap or sqlite3) into the ROS graph as raw CDR, at the recorded rate.

    tlessbot replay bags/demo.mcap
    tlessbot replay bags/demo.mcap --rate 0.5 --loop --topics /side/color/image_raw
    tlessbot replay bags/demo --wait-for-ready localiser classifier pose_estimator
"""
from __future__ import annotations

import argparse

from tlessbot_ros.io.bags import bag_topics
from tlessbot_ros.tools.support.cell_graph import PERCEPTION_NODES
from tlessbot_ros.tools.support.replay import replay


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('bag', help='bag folder or .mcap / .db3 file')
    parser.add_argument('--rate', type=float, default=1.0, help='playback speed factor')
    parser.add_argument('--loop', action='store_true', help='start again at the end')
    parser.add_argument('--topics', nargs='+', default=None, help='only these topics')
    parser.add_argument('--wait-for-subscribers', type=float, default=10.0, metavar='S',
                        help='before the first message, wait up to S seconds until every '
                             "subscriber the graph has on the bag's topics has matched (default "
                             '10); then name the topics that still have none')
    parser.add_argument('--wait-for-ready', nargs='+', default=[], metavar='NODE',
                        choices=PERCEPTION_NODES,
                        help='first wait (without a time limit) until these stage nodes report '
                             'ready on /diagnostics, so no frame reaches a stage that is still '
                             'warming up (cell.launch.py starts the replay so)')
    parser.add_argument('--no-wait', action='store_true',
                        help='start publishing at once (messages sent before a subscriber '
                             'has matched are lost to it)')
    parser.add_argument('--qos', choices=('reliable', 'sensor'), default='reliable',
                        help='QoS of the publishers')
    parser.add_argument('--restamp', action='store_true',
                        help='stamp each frame with the ROS time at which it is published '
                             '(its messages share the stamp; later loops move forward)')


def run(args: argparse.Namespace) -> int:
    import rclpy
    from rclpy.executors import ExternalShutdownException

    from tlessbot_ros.nodes.common import ignore_interrupts_while_stopping, init_ros
    from tlessbot_ros.tools.support.readiness import wait_until_ready

    bag_topics(args.bag)  # fail with one clear line before touching ROS
    init_ros()
    node = rclpy.create_node('tlessbot_replay')
    try:
        if args.wait_for_ready:
            print(f'replay: waiting for {", ".join(args.wait_for_ready)} to be ready',
                  flush=True)
            ready = wait_until_ready(args.wait_for_ready,
                                     report=lambda line: print(f'replay: {line}', flush=True))
            print(f'replay: {ready.summary()}', flush=True)
        wait_s = 0.0 if args.no_wait else args.wait_for_subscribers
        count = replay(node, args.bag, rate=args.rate, loop=args.loop, topics=args.topics,
                       qos=args.qos, wait_for_subscribers_s=wait_s, restamp=args.restamp,
                       report=lambda line: print(line, flush=True))
        print(f'replayed {count} messages from {args.bag}')
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        ignore_interrupts_while_stopping()
        node.destroy_node()
        rclpy.try_shutdown()
    return 0
