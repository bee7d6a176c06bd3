"""What the localiser spends receiving camera frames it does not admit (issue #20).

    python scripts/localiser_receive_cost.py [--rate 2] [--read-when-full]

Starts the localiser (config/cell.yaml) and a stand-in pose estimator that publishes no
outcome, so after its first two frames the entrance stays closed (``admission.min_expiry_s``
set out of reach). Then prints the localiser's CPU (share of one core, from /proc) over 30 s
idle, 30 s while ``tlessbot replay bags/demo --loop --restamp`` publishes at ``--rate`` times
the bag's 15 frames/s, and 30 s idle again. The difference is the cost of the frames the
entrance cannot take: by default it leaves them unread (``admission.pause_inputs``);
``--read-when-full`` takes each one only to refuse it, as before. Set ROS_DOMAIN_ID to a free
domain; it defaults to 79.
"""
from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

# A pose estimator that never reports an outcome: the localiser's two slots stay open.
_STAND_IN = """
import rclpy
from tlessbot_ros.nodes.common import RESULT_QOS, init_ros, message_class
init_ros()
node = rclpy.create_node('pose_estimator_stand_in')
node.create_publisher(message_class('std_msgs/msg/Header'), '/pose_estimator/frames', RESULT_QOS)
rclpy.spin(node)
"""


def share_of_a_core(pid: int, seconds: float) -> float:
    from tlessbot_ros.parallel.spare_cpu import read_process_cpu_s

    cpu0, t0 = read_process_cpu_s(pid), time.monotonic()
    time.sleep(seconds)
    return (read_process_cpu_s(pid) - cpu0) / (time.monotonic() - t0)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--rate', type=float, default=2.0, help='replay speed factor')
    parser.add_argument('--seconds', type=float, default=30.0, help='length of each window')
    parser.add_argument('--read-when-full', action='store_true',
                        help='admission.pause_inputs false: read every message while full')
    args = parser.parse_args()
    env = dict(os.environ, PYTHONPATH=str(ROOT), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
    env.setdefault('ROS_DOMAIN_ID', '79')
    quiet = dict(env=env, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    localiser = subprocess.Popen(
        [sys.executable, '-m', 'tlessbot_ros.nodes.localiser', '--ros-args', '--params-file',
         str(ROOT / 'config' / 'cell.yaml'), '-p', 'admission.min_expiry_s:=100000.0',
         '-p', f'admission.pause_inputs:={str(not args.read_when_full).lower()}'], **quiet)
    stand_in = subprocess.Popen([sys.executable, '-c', _STAND_IN], **quiet)
    try:
        time.sleep(25)   # ready, and matched with the stand-in
        print(f'idle: {100 * share_of_a_core(localiser.pid, args.seconds):.1f} % of a core')
        replay = subprocess.Popen(
            [sys.executable, '-m', 'tlessbot_ros.tools.cli', 'replay', str(ROOT / 'bags' / 'demo'),
             '--rate', str(args.rate), '--loop', '--restamp'], **quiet)
        time.sleep(15)   # the replay's wait for subscribers, then steady
        busy = share_of_a_core(localiser.pid, args.seconds)
        print(f'replay at {args.rate:g} x the bag rate, entrance closed: {100 * busy:.1f} % '
              'of a core')
        replay.send_signal(signal.SIGINT)
        replay.wait(30)
        print(f'idle again: {100 * share_of_a_core(localiser.pid, args.seconds):.1f} % of a core')
    finally:
        localiser.send_signal(signal.SIGINT)
        stand_in.kill()   # holds nothing; its spin does not return on SIGINT
        for process in (localiser, stand_in):
            try:
                process.wait(30)
            except subprocess.TimeoutExpired:
                process.kill()


if __name__ == '__main__':
    main()
