"""One replay of a cell's bag through the graph for ``tlessbot approve`` and ``tlessbot check``.

The bag is staged (:mod:`.bag_inputs`: the graph's topic names, whole frames), then replayed
by :func:`~tlessbot_ros.tools.support.graph_run.run_graph_on_bag`, lock-step unless
``--free-running``. Beside the poses it collects each part's score from ``/objects/markers``
(the label ``obj_05 (0.93)``) and, for approve, the side view's overlay from
``/objects/debug_image``; the pose estimator builds both only while someone subscribes.
"""
from __future__ import annotations

import argparse
import re
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from tlessbot_ros.conversions.topics import DEBUG_IMAGE, MARKERS
from tlessbot_ros.core.regression import PartPose
from tlessbot_ros.errors import TlessbotError
from tlessbot_ros.tools.support.bag_inputs import (
    SetupError,
    StagedBag,
    find_cameras,
    parse_camera_map,
    stage_bag,
)

_LABEL = re.compile(r'\((?P<score>[0-9.]+)\)$')   # 'obj_05 (0.93)': the score at the end
MATCH_WAIT_S = 15.0   # for the marker and overlay subscriptions to match the pose estimator
TAIL_WAIT_S = 10.0    # after the replay, for the last frames' markers and overlays


def add_replay_arguments(parser: argparse.ArgumentParser) -> None:
    """The bag and the graph's set-up, the same for approve and check."""
    from tlessbot_ros.data import DEFAULT_CLASSIFIER, DEFAULT_TEMPLATES

    parser.add_argument('bag', type=Path, help='rosbag2 folder or file (mcap or sqlite3)')
    parser.add_argument('--config', '--params-file', dest='config', type=Path,
                        help='parameter YAML of every node (default: config/cell.yaml)')
    parser.add_argument('-p', '--param', action='append', default=[], metavar='NAME:=VALUE',
                        help='a parameter for every node, after --config (repeatable)')
    parser.add_argument('--classifier', type=Path, default=DEFAULT_CLASSIFIER,
                        help='classifier .npz (default: the packaged one)')
    parser.add_argument('--templates', type=Path, default=DEFAULT_TEMPLATES,
                        help='template database .npz: the parts set (default: packaged)')
    parser.add_argument('--camera', action='append', metavar='NAME=PREFIX',
                        help="where a graph camera's topics are in the bag, e.g. "
                             'side=/camera/camera (default: found by name)')
    parser.add_argument('--free-running', action='store_true',
                        help='replay at the recorded rate (frames the graph cannot keep up '
                             'with are dropped); default: lock-step, the same answer every run')
    parser.add_argument('--startup-timeout', type=float, default=300.0, metavar='S',
                        help='seconds the graph may take to come up (default 300)')


@dataclass
class ReplayOutcome:
    """What one replay gave: parts per source stamp, the frames sent, overlays (rgb8)."""

    staged: StagedBag
    parts: list[tuple[int, PartPose]] = field(default_factory=list)
    frames: list[int] = field(default_factory=list)
    overlays: dict[int, np.ndarray] = field(default_factory=dict)
    seconds: float = 0.0


class _Extras:
    """Subscribes markers (scores) and, if asked, the overlay while the replay runs."""

    def __init__(self, overlays: bool) -> None:
        self.want_overlays = overlays
        self.scores: dict[int, list[tuple[np.ndarray, float]]] = {}
        self.overlays: dict[int, np.ndarray] = {}
        self._lock = threading.Lock()

    def _on_markers(self, msg) -> None:
        from tlessbot_ros.conversions import stamp_to_ns

        for marker in msg.markers:
            found = _LABEL.search(marker.text or '') if marker.ns == 'label' else None
            if found is None:
                continue
            p = marker.pose.position
            with self._lock:
                self.scores.setdefault(stamp_to_ns(marker.header.stamp), []).append(
                    (np.array([p.x, p.y, p.z]), float(found['score'])))

    def _on_overlay(self, msg) -> None:
        from tlessbot_ros.conversions import image_to_rgb, stamp_to_ns

        with self._lock:
            self.overlays[stamp_to_ns(msg.header.stamp)] = image_to_rgb(msg)

    def start(self, result) -> Callable[[], None]:
        """``run_graph_on_bag``'s ``alongside``: subscribe once the nodes are ready."""
        import rclpy
        from rclpy.executors import SingleThreadedExecutor

        from tlessbot_ros.nodes.common import RESULT_QOS, message_class

        node = rclpy.create_node('tlessbot_check_extras')
        subscriptions = [node.create_subscription(
            message_class('visualization_msgs/msg/MarkerArray'), MARKERS, self._on_markers,
            RESULT_QOS)]
        if self.want_overlays:
            subscriptions.append(node.create_subscription(
                message_class('sensor_msgs/msg/Image'), DEBUG_IMAGE, self._on_overlay,
                RESULT_QOS))
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        spinner = threading.Thread(target=executor.spin, daemon=True)
        spinner.start()
        deadline = time.monotonic() + MATCH_WAIT_S
        while time.monotonic() < deadline and \
                any(s.get_publisher_count() < 1 for s in subscriptions):
            time.sleep(0.05)

        def stop() -> None:
            deadline = time.monotonic() + TAIL_WAIT_S
            while time.monotonic() < deadline and not self._complete(result):
                time.sleep(0.05)
            executor.shutdown()
            spinner.join(timeout=10.0)
            node.destroy_node()
        return stop

    def _complete(self, result) -> bool:
        """Scores for every frame a pose arrived for, overlays for every frame sent (a
        MarkerArray of a frame without parts carries no stamp)."""
        with self._lock:
            scored = all(p.stamp_ns in self.scores for p in list(result.poses))
            return scored and (not self.want_overlays or
                               all(s in self.overlays for s in result.frames_replayed))

    def score(self, stamp: int, position: np.ndarray) -> float | None:
        """The score of this frame's label marker at ``position`` (within 1 mm; a label sits
        at its part's origin, in the pose's frame)."""
        best = [(float(np.linalg.norm(p - position)), s)
                for p, s in self.scores.get(stamp, ())]
        best.sort()
        return best[0][1] if best and best[0][0] < 1e-3 else None


def one_line(message: str) -> str:
    """A graph error's first line and, from the nodes' output after it, the last line that
    names an error (else the last line): 'pose_estimator exited with code 1 during start-up:
    ... output_frame must be ...'."""
    head, *rest = [line.strip() for line in message.splitlines() if line.strip()] or ['']
    errors = [line for line in rest if 'error' in line.lower()]
    detail = (errors or rest or [''])[-1]
    return f'{head.rstrip(":")}: {detail}' if detail else head.rstrip(':')


def _part_name(pose) -> str:
    return getattr(pose, 'name', None) or f'obj_{pose.obj_id:02d}'


def bag_cameras(args: argparse.Namespace) -> tuple[Path, list[str], dict[str, str]]:
    """The parameter file, its ``rig.cameras`` and {camera: prefix in the bag} of the cameras
    the graph runs with (:func:`~.bag_inputs.find_cameras`: a bag of one camera gives a rig of
    one camera).

    Raises:
        SetupError: the bag, the model files or the parameter file are missing, or the bag
            lacks topics; one line.
    """
    from tlessbot_ros.io.bags import bag_topics
    from tlessbot_ros.io.config import default_config_path
    from tlessbot_ros.tools.support.rig import load_rig

    if not args.bag.exists():
        raise SetupError(f'bag not found: {args.bag}')
    for path in (args.classifier, args.templates):
        if not Path(path).is_file():
            raise SetupError(f'model file not found: {path}')
    config = args.config or default_config_path()
    if not Path(config).is_file():
        raise SetupError(f'parameter file not found: {config}')
    cameras = list(load_rig(config).cameras)
    found = find_cameras(list(bag_topics(args.bag)), cameras, parse_camera_map(args.camera),
                         bag=str(args.bag))
    return Path(config), cameras, found


def replay_bag(args: argparse.Namespace, *, overlays: bool = False) -> ReplayOutcome:
    """Stage ``args.bag`` and replay it through the graph (see :func:`add_replay_arguments`)
    with the cameras the bag has (:func:`bag_cameras`).

    Raises:
        SetupError: the bag, its topics, the model files or the graph are not usable; one line.
    """
    from tlessbot_ros.tools.support.graph_run import run_graph_on_bag

    config, cameras, found = bag_cameras(args)
    started = time.monotonic()
    extras = _Extras(overlays)
    with tempfile.TemporaryDirectory(prefix='tlessbot_check_') as tmp:
        staged = stage_bag(args.bag, Path(tmp) / 'staged', found)
        ros_args = ['-p', f'model_path:={args.classifier}', '-p',
                    f'templates_path:={args.templates}',
                    *(a for value in args.param for a in ('-p', value))]
        argv, sys.argv = sys.argv, sys.argv[:1]   # rclpy.init reads sys.argv, where rcl
        try:                                      # would take '-p a:=b' for a remap rule
            run = run_graph_on_bag(staged.path, config=config, ros_args=ros_args,
                                   lockstep=not args.free_running,
                                   startup_timeout_s=args.startup_timeout,
                                   alongside=extras.start,
                                   cameras=None if set(found) == set(cameras) else list(found))
        except TlessbotError as error:
            raise SetupError(f'graph: {one_line(str(error))}') from None
        finally:
            sys.argv = argv
    outcome = ReplayOutcome(staged, frames=list(run.frames_replayed),
                            overlays=dict(extras.overlays),
                            seconds=time.monotonic() - started)
    for pose in run.poses:
        part = PartPose(_part_name(pose), pose.T, pose.frame_id,
                        extras.score(pose.stamp_ns, pose.T[:3, 3]))
        outcome.parts.append((pose.stamp_ns, part))
    return outcome
