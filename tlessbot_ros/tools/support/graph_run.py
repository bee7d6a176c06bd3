"""Run the perception graph on a bag and collect what it publishes (demo, bench graph, e2e).

The three perception nodes run as separate processes (as ``tlessbot launch`` starts them);
this process replays the bag's raw CDR and listens to the pose topics
(:func:`~tlessbot_ros.conversions.topics.pose_topic`) over DDS.
"""
from __future__ import annotations

import os
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from tlessbot_ros.conversions.topics import (
    COLOR,
    DEPTH,
    DIAGNOSTICS,
    camera_topic,
    classes_topic,
    labels_topic,
    pose_topic,
    relay_topic,
)
from tlessbot_ros.core.common import SIDE
from tlessbot_ros.errors import TlessbotError
from tlessbot_ros.parallel.spare_cpu import read_cpu_ticks, read_process_cpu_s
from tlessbot_ros.tools.support.processes import (
    PERCEPTION_NODES,
    GraphProcesses,
    ProcessSpec,
    graph_processes,
)

ALL_OBJECT_IDS = range(1, 31)
STAGE_OUTPUTS = {'localiser': labels_topic(SIDE), 'classifier': classes_topic(SIDE)}
MONITOR = 'replay and monitor'
# Every perception node subscribes the side depth, from the camera or (input_source:
# localiser) from the localiser's relay, once it is ready.
READY_TOPICS = (camera_topic(SIDE, DEPTH), relay_topic(SIDE, DEPTH))
FRAME_TOPIC = camera_topic(SIDE, COLOR)  # one message per replayed frame


@dataclass
class ReceivedPose:
    """A PoseStamped the graph published: source stamp, object, pose, frame, arrival time."""

    stamp_ns: int
    obj_id: int
    T: np.ndarray
    frame_id: str
    received_ns: int


@dataclass
class GraphRunResult:
    poses: list[ReceivedPose] = field(default_factory=list)
    frames_replayed: list[int] = field(default_factory=list)  # source stamps of side colour
    frames_replayed_at_ns: list[int] = field(default_factory=list)  # their publication times
    rss_mb_start: dict[str, float] = field(default_factory=dict)
    rss_mb_end: dict[str, float] = field(default_factory=dict)
    rss_mb_samples: dict[str, list[float]] = field(default_factory=dict)
    # Beside each 1 Hz RSS sample: when it was taken (monotonic s since the replay started),
    # and the open file descriptors and threads of each node (its worker processes included).
    sample_times_s: list[float] = field(default_factory=list)
    replay_start_ns: int = 0   # wall clock, as ReceivedPose.received_ns
    fd_samples: dict[str, list[int]] = field(default_factory=dict)
    thread_samples: dict[str, list[int]] = field(default_factory=dict)
    cpu_s: dict[str, float] = field(default_factory=dict)   # CPU seconds used while replaying
    # the host's CPU ticks (read_cpu_ticks) when the replay started and ended
    host_ticks: tuple[list[int] | None, list[int] | None] = (None, None)
    diagnostics: dict[str, dict[str, str]] = field(default_factory=dict)  # last, per node
    # When each stage's side output of a frame arrived here: {stage: {stamp_ns: time_ns}}
    stage_arrivals: dict[str, dict[int, int]] = field(default_factory=dict)
    node_output: str = ''


def children_by_parent() -> dict[int, list[int]]:
    """{parent pid: child pids} of every process (one scan of Linux /proc)."""
    parents: dict[int, list[int]] = {}
    for stat in Path('/proc').glob('[0-9]*/stat'):
        try:
            ppid = int(stat.read_text().rsplit(')', 1)[1].split()[1])
        except (OSError, IndexError, ValueError):
            continue
        parents.setdefault(ppid, []).append(int(stat.parent.name))
    return parents


def process_tree(pid: int, parents: dict[int, list[int]] | None = None) -> list[int]:
    """``pid`` and all its descendants (a node's worker processes count as the node's);
    ``parents`` from :func:`children_by_parent`, scanned here when not given."""
    parents = children_by_parent() if parents is None else parents
    tree, frontier = [pid], [pid]
    while frontier:
        frontier = [child for parent in frontier for child in parents.get(parent, [])]
        tree += frontier
    return tree


def cpu_seconds(pid: int, *, descendants: bool = True) -> float:
    """User + system CPU time used by a process (and its descendants), seconds (Linux /proc)."""
    total = 0.0
    for member in process_tree(pid) if descendants else [pid]:
        seconds = read_process_cpu_s(member)
        if seconds is None and member == pid:
            return float('nan')
        total += seconds or 0.0
    return total


def open_fds(pid: int, parents: dict[int, list[int]] | None = None) -> int:
    """Open file descriptors of a process and its descendants (Linux /proc; -1: none read)."""
    total, found = 0, False
    for member in process_tree(pid, parents):
        try:
            total += sum(1 for _ in Path(f'/proc/{member}/fd').iterdir())
            found = True
        except OSError:
            pass
    return total if found else -1


def thread_count(pid: int, parents: dict[int, list[int]] | None = None) -> int:
    """Threads of a process and its descendants (Linux /proc; -1: none read)."""
    total, found = 0, False
    for member in process_tree(pid, parents):
        try:
            for line in Path(f'/proc/{member}/status').read_text().splitlines():
                if line.startswith('Threads:'):
                    total += int(line.split()[1])
                    found = True
        except (OSError, ValueError):
            pass
    return total if found else -1


def rss_mb(pid: int, parents: dict[int, list[int]] | None = None) -> float:
    """Resident set size of a process and its descendants in MiB (Linux /proc; ``parents``
    as for :func:`process_tree`)."""
    total, found = 0.0, False
    for member in process_tree(pid, parents):
        try:
            for line in Path(f'/proc/{member}/status').read_text().splitlines():
                if line.startswith('VmRSS:'):
                    total += int(line.split()[1]) / 1024.0
                    found = True
        except OSError:
            pass
    return total if found else float('nan')


def run_graph_on_bag(bag: str | Path, *, config: Path, ros_args: list[str] | None = None,
                     rate: float = 1.0, loop: bool = False, duration_s: float = 0.0,
                     restamp: bool = False, startup_timeout_s: float = 300.0,
                     settle_s: float = 3.0, drain_timeout_s: float = 60.0,
                     lockstep: bool = False, quiet: bool = True,
                     node_prefixes: dict[str, list[str]] | None = None,
                     alongside: Callable[[GraphRunResult], Callable[[], None]] | None = None
                     ) -> GraphRunResult:
    """Start the perception nodes, replay ``bag`` into them, collect the published poses.

    Args:
        ros_args: extra ``--ros-args`` for every node (e.g. ``-p model_path:=...``).
        loop, duration_s: replay in a loop until ``duration_s`` seconds have passed.
        restamp: shift stamps to now (needed to measure latency; a loop without it sends
            stamps that jump back at every pass, which the nodes notice and count).
        settle_s: after the replay, wait until no pose arrived for this long ...
        drain_timeout_s: ... and, up to this long, until the pose estimator's /diagnostics
            count (frames + failures) covers every replayed frame.
        lockstep: publish one frame (all messages sharing a log time), then wait until the
            pose estimator has handled it before the next (no frame is dropped; for scoring,
            not for timing). ``rate`` and ``loop`` are ignored.
        node_prefixes: an argv prefix per node label, e.g. ``ip netns exec NS`` to start that
            node in another network namespace (a second host; :mod:`.netns`).
        alongside: called with the result as the replay starts (the nodes are ready); what
            it returns is called when the replay ends, before the drain (bench fuzz starts
            and stops its garbage publisher so).
    """
    import rclpy
    from rclpy.executors import SingleThreadedExecutor

    from tlessbot_ros.conversions.cdr import header_stamp_ns
    from tlessbot_ros.conversions.pose import pose_stamped_to_transform
    from tlessbot_ros.nodes.common import RESULT_QOS, init_ros, message_class
    from tlessbot_ros.tools.support.replay import replay

    if lockstep:  # one frame at a time: no frame may be skipped by a rate cap
        ros_args = [*(ros_args or []), '-p', 'sync.max_rate_hz:=0.0']
    specs = [ProcessSpec(spec.label, [*(node_prefixes or {}).get(spec.label, []), *spec.argv])
             for spec in graph_processes(config, nodes=list(PERCEPTION_NODES),
                                         extra_ros_args=ros_args)]
    graph = GraphProcesses(specs, env=dict(os.environ))
    result = GraphRunResult()
    output: list[str] = []
    init_ros()
    monitor = rclpy.create_node('tlessbot_graph_monitor')
    player = rclpy.create_node('tlessbot_graph_replay')
    executor = SingleThreadedExecutor()
    executor.add_node(monitor)
    spinner = threading.Thread(target=executor.spin, daemon=True)
    lock = threading.Lock()
    last_pose = [time.monotonic()]

    def on_pose(obj_id: int):
        def callback(msg) -> None:
            T, frame_id, stamp = pose_stamped_to_transform(msg)
            with lock:
                result.poses.append(ReceivedPose(stamp, obj_id, T, frame_id, time.time_ns()))
                last_pose[0] = time.monotonic()
        return callback

    handled = [0]
    work_seen = [time.monotonic(), ()]   # when the stages' frame counts last changed, and them

    def on_diagnostics(msg) -> None:
        for status in msg.status:
            values = {kv.key: kv.value for kv in status.values}
            result.diagnostics[status.name] = values
            if status.name == 'pose_estimator':
                handled[0] = int(values.get('frames', 0)) + int(values.get('failures', 0))
        counts = tuple(result.diagnostics.get(name, {}).get(key) for name in PERCEPTION_NODES
                       for key in ('frames', 'failures', 'dropped'))
        if counts != work_seen[1]:
            work_seen[:] = [time.monotonic(), counts]

    monitor.create_subscription(message_class('diagnostic_msgs/msg/DiagnosticArray'),
                                DIAGNOSTICS, on_diagnostics, RESULT_QOS)
    def on_stage_output(stage: str):
        arrivals = result.stage_arrivals.setdefault(stage, {})

        def callback(data: bytes) -> None:
            try:
                arrivals[header_stamp_ns(data)] = time.time_ns()
            except ValueError:   # not from the stage (bench fuzz publishes garbage here)
                pass
        return callback

    image_class = message_class('sensor_msgs/msg/Image')
    for stage, topic in STAGE_OUTPUTS.items():   # raw: only the stamp is read
        monitor.create_subscription(image_class, topic, on_stage_output(stage), RESULT_QOS,
                                    raw=True)
    pose_class = message_class('geometry_msgs/msg/PoseStamped')
    for obj_id in ALL_OBJECT_IDS:
        monitor.create_subscription(pose_class, pose_topic(obj_id), on_pose(obj_id), RESULT_QOS)
    try:
        if quiet:
            graph.start_capturing(output)
        else:
            graph.start()
        spinner.start()
        deadline = time.monotonic() + startup_timeout_s
        # Ready when every perception node subscribes the side depth.
        while sum(player.count_subscribers(t) for t in READY_TOPICS) < len(PERCEPTION_NODES):
            exited = graph.first_exited()
            if exited is not None:
                raise TlessbotError(f'{exited[0]} exited with code {exited[1]} during start-up:'
                                    f'\n{"".join(output[-20:])}')
            if time.monotonic() > deadline:
                raise TlessbotError('the perception nodes did not come up within '
                                    f'{startup_timeout_s:.0f} s:\n{"".join(output[-20:])}')
            time.sleep(0.2)
        time.sleep(1.0)  # let DDS match the remaining topics
        pids = {spec.label: graph.children[spec.label].pid for spec in specs}
        result.rss_mb_start = {label: rss_mb(pid) for label, pid in pids.items()}
        cpu_pids = {**pids, MONITOR: os.getpid()}

        def cpu_now(label: str) -> float:   # the monitor's children are the nodes
            return cpu_seconds(cpu_pids[label], descendants=label != MONITOR)
        cpu_start = {label: cpu_now(label) for label in cpu_pids}
        host_start = read_cpu_ticks()
        replay_start = time.monotonic()
        result.replay_start_ns = time.time_ns()
        stop_at = replay_start + duration_s if duration_s else None
        end_alongside = alongside(result) if alongside is not None else None
        next_sample = [replay_start]

        def on_publish(message) -> None:
            if message.topic == FRAME_TOPIC:
                result.frames_replayed.append(header_stamp_ns(message.raw))
                result.frames_replayed_at_ns.append(time.time_ns())
            if time.monotonic() >= next_sample[0]:
                parents = children_by_parent()   # one /proc scan per sample: replay thread
                result.sample_times_s.append(time.monotonic() - replay_start)
                for label, pid in pids.items():
                    result.rss_mb_samples.setdefault(label, []).append(rss_mb(pid, parents))
                    result.fd_samples.setdefault(label, []).append(open_fds(pid, parents))
                    result.thread_samples.setdefault(label, []).append(
                        thread_count(pid, parents))
                next_sample[0] = time.monotonic() + 1.0

        if lockstep:
            _replay_lockstep(player, str(bag), handled, on_publish, graph, drain_timeout_s)
        else:
            # as tlessbot replay does: not before every subscriber has matched (a message sent
            # earlier is lost to it; under load discovery of ~20 topics takes seconds)
            replay(player, str(bag), rate=rate, loop=loop, restamp=restamp,
                   wait_for_subscribers_s=30.0, on_publish=on_publish,
                   should_stop=(lambda: stop_at is not None and time.monotonic() > stop_at))
        if end_alongside is not None:
            end_alongside()
        result.cpu_s = {label: cpu_now(label) - cpu_start[label] for label in cpu_pids}
        result.host_ticks = (host_start, read_cpu_ticks())
        drain_until = time.monotonic() + drain_timeout_s
        with lock:
            last_pose[0] = time.monotonic()
        while time.monotonic() < drain_until and graph.first_exited() is None:
            time.sleep(0.1)
            quiet = time.monotonic() - last_pose[0] > settle_s
            # every frame answered, or (frames were dropped) no stage has counted anything new
            # for a while: the graph is done with the replay
            if quiet and (handled[0] >= len(result.frames_replayed)
                          or time.monotonic() - work_seen[0] > settle_s + 1.0):
                break
        exited = graph.first_exited()
        if exited is not None:
            raise TlessbotError(f'{exited[0]} exited with code {exited[1]}:\n'
                                f'{"".join(output[-20:])}')
        result.rss_mb_end = {label: rss_mb(pid) for label, pid in pids.items()}
    finally:
        graph.stop()
        executor.shutdown()
        if spinner.is_alive():   # a spinning executor thread left behind aborts the exit
            spinner.join(timeout=10.0)
        monitor.destroy_node()
        player.destroy_node()
        rclpy.try_shutdown()
        result.node_output = ''.join(output)
    return result


def _replay_lockstep(node, bag: str, handled: list[int], on_publish, graph: GraphProcesses,
                     frame_timeout_s: float) -> None:
    """Publish frame after frame, each once the pose estimator reported the previous one."""
    from itertools import groupby

    from tlessbot_ros.io.bags import bag_topics, read_bag
    from tlessbot_ros.nodes.common import RESULT_QOS, message_class
    from tlessbot_ros.tools.support.replay import wait_for_matches

    publishers = {topic: node.create_publisher(message_class(msgtype), topic, RESULT_QOS)
                  for topic, msgtype in bag_topics(bag).items()}
    wait_for_matches(node, publishers, timeout_s=30.0)  # a first frame is lost otherwise
    for count, (_, messages) in enumerate(groupby(read_bag(bag), key=lambda m: m.log_time_ns),
                                          start=1):
        for message in messages:
            publishers[message.topic].publish(message.raw)
            on_publish(message)
        deadline = time.monotonic() + frame_timeout_s
        while handled[0] < count and time.monotonic() < deadline:
            if graph.first_exited() is not None:
                return
            time.sleep(0.05)
