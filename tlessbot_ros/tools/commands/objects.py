"""Ask the graph what is on the table now (GetObjects) and print every part, as an arm would.

Each answer lists every part of the next frame the graph completes: part, instance name,
score, position in the requested frame and in the world composed from /tf_static and /tf.

    tlessbot objects                         # one request, every part, world frame
    tlessbot objects --parts obj_05 --frame side_color_optical_frame
    tlessbot objects --count 10 --interval 0.5 --json
"""
from __future__ import annotations

import argparse
import json
import threading
import time

from tlessbot_ros.errors import TlessbotError


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('--parts', nargs='+', default=[], help='part names (default: all)')
    parser.add_argument('--frame', default='', help='frame of the poses (default: world)')
    parser.add_argument('--frames', type=int, default=1,
                        help='frames that must agree before the answer (default 1)')
    parser.add_argument('--timeout', type=float, default=5.0, help='seconds per request')
    parser.add_argument('--count', type=int, default=1,
                        help='requests to make (default 1; 0: until --stop-after-failures)')
    parser.add_argument('--stop-after-failures', type=int, default=0, metavar='N',
                        help='stop after N unanswered requests in a row once one was '
                             'answered (default 0: never)')
    parser.add_argument('--interval', type=float, default=0.0,
                        help='seconds between the requests (default 0)')
    parser.add_argument('--json', action='store_true', help='one JSON object per answer')
    parser.add_argument('--wait-for-service', type=float, default=30.0,
                        help='seconds to wait for the objects node (default 30)')


def answer_record(answer) -> dict:
    """The JSON record of one answer (pure: tested without ROS)."""
    def pose(T):
        return None if T is None else [[round(float(v), 6) for v in row] for row in T]
    return {'success': answer.success, 'message': answer.message, 'stamp_ns': answer.stamp_ns,
            'latency_s': round(answer.latency_s, 6),
            'parts': [{'part': p.part, 'instance': p.instance, 'score': round(p.score, 4),
                       'frame_id': p.frame_id, 'T_frame_part': pose(p.T_frame_part),
                       'T_world_part_tf': pose(p.T_world_part_tf),
                       'box_size_m': [round(v, 4) for v in p.box_size_m]}
                      for p in answer.parts]}


def format_answer(answer) -> str:
    """Human-readable lines of one answer (pure)."""
    if not answer.success:
        return f'no answer: {answer.message}'
    lines = [f'{len(answer.parts)} parts at stamp {answer.stamp_ns * 1e-9:.3f} s '
             f'(answered in {answer.latency_s * 1e3:.0f} ms)']
    for p in answer.parts:
        x, y, z = p.T_frame_part[:3, 3]
        lines.append(f'  {p.instance:<12} {p.part:<8} score {p.score:.2f}  '
                     f'{p.frame_id}: x={x:+.4f} y={y:+.4f} z={z:+.4f}')
    return '\n'.join(lines)


def run(args: argparse.Namespace) -> int:
    import rclpy
    from rclpy.executors import SingleThreadedExecutor

    from tlessbot_ros.tools.support.arm_client import ArmClient

    if args.count < 0 or args.timeout <= 0 or (args.count == 0 and not args.stop_after_failures):
        raise TlessbotError('--count must be >= 0 (0 needs --stop-after-failures) and '
                            '--timeout > 0')
    rclpy.init()
    node = rclpy.create_node('tlessbot_objects')
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    stop = threading.Event()

    def spin() -> None:
        while not stop.is_set():
            executor.spin_once(timeout_sec=0.05)
    spinner = threading.Thread(target=spin, daemon=True)
    spinner.start()
    try:
        client = ArmClient(node)
        if not client.wait_for_service(args.wait_for_service):
            raise TlessbotError('no /objects/get_objects service: is the objects node running?')
        answered = in_a_row = k = 0
        while args.count == 0 or k < args.count:
            k += 1
            answer = client.request(parts=args.parts, frame_id=args.frame, frames=args.frames,
                                    timeout_s=args.timeout)
            answered += answer.success
            in_a_row = 0 if answer.success else in_a_row + 1
            print(json.dumps(answer_record(answer)) if args.json else format_answer(answer),
                  flush=True)
            if answered and args.stop_after_failures and in_a_row >= args.stop_after_failures:
                break
            time.sleep(args.interval)
        return 0 if answered else 1
    finally:
        stop.set()
        spinner.join()
        executor.shutdown(timeout_sec=1.0)
        node.destroy_node()
        rclpy.try_shutdown()
