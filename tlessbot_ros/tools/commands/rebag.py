"""Rewrite a bag as a chunk-compressed mcap bag that every tool reads (CDR bytes unchanged).

    tlessbot rebag old_run new_run

For bags written before tlessbot compressed chunks instead of messages (each message its own
zstd frame, which Foxglove, mcap readers and ros2 bag play cannot decode), or any rosbag2 bag
(mcap or sqlite3). Topics, types, log times, offered QoS and every message's CDR bytes are
kept; the output is what the simulator and ``tlessbot record`` write now.
"""
from __future__ import annotations

import argparse


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('source', help='bag folder or .mcap / .db3 file to read')
    parser.add_argument('out', help='output bag folder (must not exist)')
    parser.add_argument('--no-compress', action='store_true',
                        help='write uncompressed chunks')


def run(args: argparse.Namespace) -> int:
    from tlessbot_ros.io.bag_writer import BagWriter
    from tlessbot_ros.io.bags import bag_offered_qos, bag_topics, read_bag

    types = bag_topics(args.source)
    offers = bag_offered_qos(args.source)
    with BagWriter(args.out, compress=not args.no_compress) as bag:
        for topic, msgtype in types.items():
            bag.add_topic(topic, msgtype, offers[topic])
        for message in read_bag(args.source):
            bag.write(message.topic, message.log_time_ns, message.raw)
    print(f'rewrote {sum(bag.counts.values())} messages on {len(types)} topics into {args.out}')
    return 0
