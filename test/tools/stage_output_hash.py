"""SHA-1 of everything the three stage nodes publish on a bag's frames (a bit-exact check).

    PYTHONPATH=$PWD python test/tools/stage_output_hash.py [--bag bags/demo] [--repeats 2]
        [--pose-workers 0] [--poses FILE.npz] [--per-frame]

The frames go through LocaliserNode, ClassifierNode and PoseEstimatorNode in-process as
``tlessbot bench nodes`` feeds them (no DDS). Hashed, frame by frame: the labels and classes
images as published (CDR bytes) and every pose message (frame, stamp and the seven float64 of
its pose, bit for bit; not its CDR bytes, whose padding is left open), a frame's poses sorted
by topic and content (with a worker process they go out in the order they finish). Run it in
two checkouts (a checkout without this file runs it from another path with its own
PYTHONPATH): the same line means the same outputs. ``--per-frame`` prints each frame's three
digests, ``--poses`` writes each frame's poses (obj_id, position, quaternion) to compare
values when the digests differ.
"""
from __future__ import annotations

import argparse
import hashlib
import os
import sys

import numpy as np


class _Recorder:
    """Stands in for a publisher: keeps every message."""

    def __init__(self) -> None:
        self.messages: list = []

    @property
    def last(self):
        return self.messages[-1]

    def publish(self, msg) -> None:
        self.messages.append(msg)

    def get_subscription_count(self) -> int:
        return 0


def _pose_bytes(msg) -> bytes:
    """A PoseStamped's content as bytes (its CDR serialisation leaves padding bytes open)."""
    p, q = msg.pose.position, msg.pose.orientation
    return (msg.header.frame_id.encode() + b'\0'
            + np.array([msg.header.stamp.sec, msg.header.stamp.nanosec], '<i8').tobytes()
            + np.array([p.x, p.y, p.z, q.x, q.y, q.z, q.w], '<f8').tobytes())


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--bag', default=None)
    parser.add_argument('--repeats', type=int, default=2)
    parser.add_argument('--pose-workers', type=int, default=0)
    parser.add_argument('--poses', default=None, metavar='FILE.npz')
    parser.add_argument('--per-frame', action='store_true',
                        help='also print the digests of each frame (labels, classes, poses)')
    args = parser.parse_args()

    import rclpy
    from rclpy.parameter import Parameter

    from tlessbot_ros.conversions.image_cdr import image_from_cdr
    from tlessbot_ros.core.common import CAMERA_NAMES
    from tlessbot_ros.nodes.classifier import ClassifierNode
    from tlessbot_ros.nodes.common import init_ros, limit_blas_threads
    from tlessbot_ros.nodes.localiser import LocaliserNode
    from tlessbot_ros.nodes.pose_estimator import PoseEstimatorNode
    from tlessbot_ros.tools.commands.bench.nodes import bag_frames
    from tlessbot_ros.tools.support.defaults import DEFAULT_BAG

    frames = bag_frames(args.bag or str(DEFAULT_BAG))
    limit_blas_threads()
    init_ros()
    digest = hashlib.sha1()
    poses: dict[str, np.ndarray] = {}
    try:
        localiser = LocaliserNode()
        classifier = ClassifierNode()
        pose = PoseEstimatorNode(parameter_overrides=[
            Parameter('workers.count', value=args.pose_workers)])
        for node in (localiser, classifier, pose):
            if not node.wait_ready():
                print(f'{node.get_name()} did not get ready: {node.last_error}')
                return 1
        labels = {c: _Recorder() for c in CAMERA_NAMES}
        classes = {c: _Recorder() for c in CAMERA_NAMES}
        localiser._label_publishers, classifier._class_publishers = labels, classes
        pose_out = {k: _Recorder() for k in pose._pose_publishers}
        pose._pose_publishers = pose_out
        pose._markers, pose._overlay = _Recorder(), _Recorder()
        for n in range(max(1, args.repeats) * len(frames)):
            views = {c: dict(msgs) for c, msgs in frames[n % len(frames)].items()}
            parts = {key: hashlib.sha1() for key in ('labels', 'classes', 'poses')}
            localiser.process(views)
            for c in views:
                parts['labels'].update(labels[c].last)
                views[c]['labels'] = image_from_cdr(labels[c].last)
            classifier.process(views)
            for c in views:
                parts['classes'].update(classes[c].last)
                views[c]['classes'] = image_from_cdr(classes[c].last)
            pose.process(views)
            sent = sorted(((obj_id, _pose_bytes(m), m)
                           for obj_id, rec in pose_out.items() for m in rec.messages),
                          key=lambda item: item[:2])
            for obj_id, data, _ in sent:
                parts['poses'].update(obj_id.to_bytes(2, 'little') + data)
            for part in parts.values():
                digest.update(part.digest())
            if args.per_frame:
                print(f'frame {n}: ' + ' '.join(f'{k} {v.hexdigest()[:10]}'
                                                for k, v in parts.items()))
            poses[f'frame_{n:03d}'] = np.array(
                [[obj_id, m.pose.position.x, m.pose.position.y, m.pose.position.z,
                  m.pose.orientation.x, m.pose.orientation.y, m.pose.orientation.z,
                  m.pose.orientation.w] for obj_id, _, m in sent]).reshape(-1, 8)
            for rec in pose_out.values():
                rec.messages.clear()
        for node in (localiser, classifier, pose):
            node.destroy_node()
    finally:
        rclpy.try_shutdown()
    if args.poses:
        np.savez(args.poses, **poses)
    print(f'{digest.hexdigest()}  {len(frames)} frames x {max(1, args.repeats)} passes, '
          f'pose workers {args.pose_workers}, {sum(len(p) for p in poses.values())} poses, '
          f'{os.getcwd()}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
