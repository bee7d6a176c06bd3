#!/usr/bin/env python3
"""Does rclpy's EventsExecutor keep running while another thread creates entities?

A stage node creates its subscriptions on its warm-up thread while its executor spins, so the
executor it spins must survive that. This script spins one node with rclpy's EventsExecutor
in one of two ways, while a second thread creates ``--entities`` publisher/subscription pairs
and a 100 Hz timer publishes to the node's own subscription:

- ``spin_once`` (the default): :func:`tlessbot_ros.nodes.common.spin_until_interrupted`, the
  loop every node's ``main()`` runs (``spin_once`` with a timeout, on the main thread);
- ``spin``: rclpy's own ``EventsExecutor.spin()``.

It prints one line, ``ok`` with the counts, and exits 0, or ``STUCK`` and exits 2 when
nothing was created for ``--stall-s`` seconds. A stall can hold the interpreter lock, so the
caller should also kill it after a timeout (exit 137 under ``timeout -s KILL``).

    ROS_DOMAIN_ID=71 timeout -s KILL 60 python scripts/events_executor_check.py --how spin_once
    ROS_DOMAIN_ID=71 timeout -s KILL 60 python scripts/events_executor_check.py --how spin

On rclpy 7.1.5 (Jazzy) the first created 1000 pairs in each of 20 runs; the second stalled
in 5 of 5 runs of 300, at 100 % of a core holding the interpreter lock
(docs/bench/backpressure.md).
"""
from __future__ import annotations

import argparse
import os
import threading
import time


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--how', choices=('spin_once', 'spin'), default='spin_once')
    parser.add_argument('--entities', type=int, default=300,
                        help='publisher/subscription pairs the second thread creates')
    parser.add_argument('--stall-s', type=float, default=10.0,
                        help='report STUCK when nothing was created for this long')
    args = parser.parse_args()

    import rclpy
    from rclpy.executors import ExternalShutdownException
    from rclpy.experimental import EventsExecutor
    from sensor_msgs.msg import Image
    from std_msgs.msg import Header

    from tlessbot_ros.nodes.common import spin_until_interrupted

    rclpy.init()
    node = rclpy.create_node(f'events_executor_check_{os.getpid()}')
    ticks = [0]
    tick_publisher = node.create_publisher(Header, 'tick', 10)
    node.create_subscription(Header, 'tick', lambda _msg: ticks.__setitem__(0, ticks[0] + 1),
                             10)
    node.create_timer(0.01, lambda: tick_publisher.publish(Header()))
    created = [0]
    finished = threading.Event()
    kept = []   # the entities stay alive until the end, as a node's subscriptions do

    def create_entities() -> None:
        for index in range(args.entities):
            kept.append(node.create_publisher(Image, f'check_image_{index}', 2))
            kept.append(node.create_subscription(Image, f'check_image_{index}',
                                                 lambda _msg: None, 2))
            created[0] += 1
            time.sleep(0.001)
        # the timer must still fire after the last creation
        ticks_then = ticks[0]
        deadline = time.monotonic() + args.stall_s
        while ticks[0] == ticks_then and time.monotonic() < deadline:
            time.sleep(0.01)
        finished.set()
        rclpy.try_shutdown()   # ends spin_until_interrupted; wakes spin()

    def watchdog() -> None:
        # on its own thread: reports a stall while the spinning thread is stuck in C++
        last = -1
        while not finished.wait(args.stall_s):
            if created[0] == last:
                print(f'{args.how}: STUCK after {created[0]} of {args.entities} pairs, '
                      f'{ticks[0]} timer messages', flush=True)
                os._exit(2)
            last = created[0]

    threading.Thread(target=create_entities, daemon=True).start()
    threading.Thread(target=watchdog, daemon=True).start()
    started = time.monotonic()
    try:
        if args.how == 'spin_once':
            spin_until_interrupted(node, 'events')
        else:
            executor = EventsExecutor(context=node.context)
            executor.add_node(node)
            executor.spin()
    except ExternalShutdownException:   # the creating thread's shutdown, as run_node takes it
        pass
    print(f'{args.how}: ok, {created[0]} of {args.entities} pairs created in '
          f'{time.monotonic() - started:.1f} s, {ticks[0]} timer messages', flush=True)
    os._exit(0 if created[0] == args.entities and finished.is_set() else 2)


if __name__ == '__main__':
    main()
