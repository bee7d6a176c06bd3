"""Run the perception graph on a bag and collect what it publishes (demo, bench graph, e2e).

The three perception nodes run as separate processes (as ``tlessbot launch`` starts them);
this process replays the bag's raw CDR and listens to the pose topics
(:func:`~tlessbot_ros.conversions.topics.pose_topic`) over DDS. A :class:`GraphRun` does it in
four steps (start, wait until ready, replay, drain) with two helpers: a :class:`GraphMonitor`
that records what the graph publishes and a :class:`ProcessSampler` that measures its
processes (:mod:`.proc_stats`) while the bag plays.
"""
from __future__ import annotations

import os
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

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
from tlessbot_ros.parallel.spare_cpu import read_cpu_ticks
from tlessbot_ros.tools.support.proc_stats import (
    children_by_parent,
    cpu_seconds,
    open_fds,
    rss_mb,
    thread_count,
)
from tlessbot_ros.tools.support.processes import (
    PERCEPTION_NODES,
    GraphProcesses,
    ProcessSpec,
    graph_processes,
)

ALL_OBJECT_IDS = range(1, 31)
MONITOR = 'replay and monitor'


def stage_outputs(camera: str = SIDE) -> dict[str, str]:
    """The topics of each stage's output of ``camera`` (side, or a rig's one camera)."""
    return {'localiser': labels_topic(camera), 'classifier': classes_topic(camera)}


def ready_topics(camera: str = SIDE) -> tuple[str, str]:
    """Every perception node subscribes ``camera``'s depth, from the camera or (input_source:
    localiser) from the localiser's relay, once it is ready."""
    return camera_topic(camera, DEPTH), relay_topic(camera, DEPTH)


STAGE_OUTPUTS = stage_outputs()
READY_TOPICS = ready_topics()
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
    frames_replayed: list[int] = field(default_factory=list)  # main camera's colour stamps
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


@dataclass(frozen=True)
class GraphRunOptions:
    """How a :class:`GraphRun` replays and waits (see :func:`run_graph_on_bag`)."""

    rate: float = 1.0
    loop: bool = False
    duration_s: float = 0.0
    restamp: bool = False
    startup_timeout_s: float = 300.0
    settle_s: float = 3.0
    drain_timeout_s: float = 60.0
    lockstep: bool = False
    quiet: bool = True
    cameras: tuple[str, ...] | None = None   # rig.cameras of the run; None: the config's


def main_camera(cameras: Sequence[str] | None) -> str:
    """The camera whose frames the run counts and waits on: side, or a rig's one camera."""
    from tlessbot_ros.core.label_views import view_order

    return view_order(cameras)[0] if cameras else SIDE


class GraphMonitor:
    """Records what the graph publishes into a :class:`GraphRunResult`: the poses, when each
    stage's side output of a frame arrived, and the nodes' last /diagnostics (its callbacks
    run on the executor's thread)."""

    def __init__(self, node: Any, result: GraphRunResult,
                 part_names: dict[int, str] | None = None, camera: str = SIDE) -> None:
        from tlessbot_ros.nodes.common import RESULT_QOS, message_class

        self.result = result
        self.lock = threading.Lock()
        self.last_pose_s = time.monotonic()
        self.handled = 0                      # frames the pose estimator reported done
        self.work_changed_s = time.monotonic()   # when the stages' counts last changed
        self._work_counts: tuple = ()
        node.create_subscription(message_class('diagnostic_msgs/msg/DiagnosticArray'),
                                 DIAGNOSTICS, self._on_diagnostics, RESULT_QOS)
        image_class = message_class('sensor_msgs/msg/Image')
        for stage, topic in stage_outputs(camera).items():   # raw: only the stamp is read
            node.create_subscription(image_class, topic, self._on_stage_output(stage),
                                     RESULT_QOS, raw=True)
        pose_class = message_class('geometry_msgs/msg/PoseStamped')
        for obj_id in (ALL_OBJECT_IDS if part_names is None else sorted(part_names)):
            node.create_subscription(pose_class, pose_topic(obj_id, part_names),
                                     self._on_pose(obj_id), RESULT_QOS)

    def _on_pose(self, obj_id: int) -> Callable[[Any], None]:
        from tlessbot_ros.conversions.pose import pose_stamped_to_transform

        def callback(msg: Any) -> None:
            T, frame_id, stamp = pose_stamped_to_transform(msg)
            with self.lock:
                self.result.poses.append(ReceivedPose(stamp, obj_id, T, frame_id,
                                                      time.time_ns()))
                self.last_pose_s = time.monotonic()
        return callback

    def _on_diagnostics(self, msg: Any) -> None:
        for status in msg.status:
            values = {kv.key: kv.value for kv in status.values}
            self.result.diagnostics[status.name] = values
            if status.name == 'pose_estimator':
                self.handled = int(values.get('frames', 0)) + int(values.get('failures', 0))
        counts = tuple(self.result.diagnostics.get(name, {}).get(key)
                       for name in PERCEPTION_NODES for key in ('frames', 'failures', 'dropped'))
        if counts != self._work_counts:
            self.work_changed_s, self._work_counts = time.monotonic(), counts

    def _on_stage_output(self, stage: str) -> Callable[[bytes], None]:
        from tlessbot_ros.conversions.cdr import header_stamp_ns

        arrivals = self.result.stage_arrivals.setdefault(stage, {})

        def callback(data: bytes) -> None:
            try:
                arrivals[header_stamp_ns(data)] = time.time_ns()
            except ValueError:   # not from the stage (bench fuzz publishes garbage here)
                pass
        return callback

    def restart_quiet_clock(self) -> None:
        """Count the silence of the pose topics from now."""
        with self.lock:
            self.last_pose_s = time.monotonic()

    def done(self, settle_s: float) -> bool:
        """No pose for ``settle_s``, and every replayed frame answered or (frames were
        dropped) no stage has counted anything new for a while: the graph is done."""
        now = time.monotonic()
        return now - self.last_pose_s > settle_s and (
            self.handled >= len(self.result.frames_replayed)
            or now - self.work_changed_s > settle_s + 1.0)


class ProcessSampler:
    """The nodes' CPU over the replay, and once a second their RSS, open files and threads
    (their worker processes included), taken on the replay's thread as frames go out."""

    def __init__(self, pids: dict[str, int], result: GraphRunResult,
                 frame_topic: str = FRAME_TOPIC) -> None:
        self.pids, self.frame_topic = pids, frame_topic
        self.result = result
        self._cpu_pids = {**pids, MONITOR: os.getpid()}
        self._cpu_start = {label: self._cpu(label) for label in self._cpu_pids}
        self._host_start = read_cpu_ticks()
        self.start_s = time.monotonic()
        result.replay_start_ns = time.time_ns()
        self._next_sample_s = self.start_s

    def _cpu(self, label: str) -> float:
        # the monitor's children are the nodes: its own time alone
        return cpu_seconds(self._cpu_pids[label], descendants=label != MONITOR)

    def on_publish(self, message: Any) -> None:
        """Called with every replayed message: notes the frames, samples when one is due."""
        from tlessbot_ros.conversions.cdr import header_stamp_ns

        if message.topic == self.frame_topic:
            self.result.frames_replayed.append(header_stamp_ns(message.raw))
            self.result.frames_replayed_at_ns.append(time.time_ns())
        if time.monotonic() >= self._next_sample_s:
            self._sample()
            self._next_sample_s = time.monotonic() + 1.0

    def _sample(self) -> None:
        result = self.result
        parents = children_by_parent()   # one /proc scan per sample
        result.sample_times_s.append(time.monotonic() - self.start_s)
        for label, pid in self.pids.items():
            result.rss_mb_samples.setdefault(label, []).append(rss_mb(pid, parents))
            result.fd_samples.setdefault(label, []).append(open_fds(pid, parents))
            result.thread_samples.setdefault(label, []).append(thread_count(pid, parents))

    def finish(self) -> None:
        """The CPU each used since the replay started, and the host's ticks."""
        self.result.cpu_s = {label: self._cpu(label) - self._cpu_start[label]
                             for label in self._cpu_pids}
        self.result.host_ticks = (self._host_start, read_cpu_ticks())


class GraphRun:
    """The perception nodes started as processes, ``bag`` replayed into them, what they
    publish collected: :meth:`run` once (arguments as :func:`run_graph_on_bag`)."""

    def __init__(self, bag: str | Path, *, config: Path, options: GraphRunOptions,
                 ros_args: list[str] | None = None,
                 node_prefixes: dict[str, list[str]] | None = None,
                 alongside: Callable[[GraphRunResult], Callable[[], None]] | None = None,
                 part_names: dict[int, str] | None = None) -> None:
        if options.lockstep:  # one frame at a time: no frame may be skipped by a rate cap
            ros_args = [*(ros_args or []), '-p', 'sync.max_rate_hz:=0.0']
        if options.cameras:
            ros_args = [*(ros_args or []), '-p', f'rig.cameras:=[{", ".join(options.cameras)}]']
        self.camera = main_camera(options.cameras)
        self.bag, self.options, self.alongside = str(bag), options, alongside
        self.specs = [ProcessSpec(spec.label,
                                  [*(node_prefixes or {}).get(spec.label, []), *spec.argv])
                      for spec in graph_processes(config, nodes=list(PERCEPTION_NODES),
                                                  extra_ros_args=ros_args)]
        self.graph = GraphProcesses(self.specs, env=dict(os.environ))
        self.result = GraphRunResult()
        self.output: list[str] = []
        self.player: Any = None        # the replaying node, made in run()
        self.monitor: GraphMonitor | None = None
        self.part_names = part_names

    def run(self) -> GraphRunResult:
        """Start, wait until ready, replay, drain; the nodes are stopped in any case."""
        import rclpy
        from rclpy.executors import SingleThreadedExecutor

        from tlessbot_ros.nodes.common import init_ros

        init_ros()
        monitor_node = rclpy.create_node('tlessbot_graph_monitor')
        self.player = rclpy.create_node('tlessbot_graph_replay')
        self.monitor = GraphMonitor(monitor_node, self.result, self.part_names, self.camera)
        self.executor = SingleThreadedExecutor()
        self.executor.add_node(monitor_node)
        spinner = threading.Thread(target=self.executor.spin, daemon=True)
        try:
            self._start(spinner)
            pids = self._wait_until_ready()
            self.result.rss_mb_start = {label: rss_mb(pid) for label, pid in pids.items()}
            sampler = ProcessSampler(pids, self.result, camera_topic(self.camera, COLOR))
            self._replay(sampler)
            self._drain()
            self.result.rss_mb_end = {label: rss_mb(pid) for label, pid in pids.items()}
        finally:
            self.graph.stop()
            self.executor.shutdown()
            if spinner.is_alive():   # a spinning executor thread left behind aborts the exit
                spinner.join(timeout=10.0)
            monitor_node.destroy_node()
            self.player.destroy_node()
            rclpy.try_shutdown()
            self.result.node_output = ''.join(self.output)
        return self.result

    def _start(self, spinner: threading.Thread) -> None:
        if self.options.quiet:
            self.graph.start_capturing(self.output)
        else:
            self.graph.start()
        spinner.start()

    def _wait_until_ready(self) -> dict[str, int]:
        """Until every perception node subscribes the main camera's depth; the nodes' pids."""
        deadline = time.monotonic() + self.options.startup_timeout_s
        while sum(self.player.count_subscribers(t) for t in ready_topics(self.camera)) < \
                len(PERCEPTION_NODES):
            self._raise_if_exited(' during start-up')
            if time.monotonic() > deadline:
                raise TlessbotError('the perception nodes did not come up within '
                                    f'{self.options.startup_timeout_s:.0f} s:\n'
                                    f'{"".join(self.output[-20:])}')
            time.sleep(0.2)
        time.sleep(1.0)  # let DDS match the remaining topics
        return {spec.label: self.graph.children[spec.label].pid for spec in self.specs}

    def _replay(self, sampler: ProcessSampler) -> None:
        from tlessbot_ros.tools.support.replay import replay

        options = self.options
        stop_at = sampler.start_s + options.duration_s if options.duration_s else None
        end_alongside = self.alongside(self.result) if self.alongside is not None else None
        if options.lockstep:
            _replay_lockstep(self.player, self.bag, lambda: self.monitor.handled,
                             sampler.on_publish, self.graph, options.drain_timeout_s)
        else:
            # as tlessbot replay does: not before every subscriber has matched (a message sent
            # earlier is lost to it; under load discovery of ~20 topics takes seconds)
            replay(self.player, self.bag, rate=options.rate, loop=options.loop,
                   restamp=options.restamp, wait_for_subscribers_s=30.0,
                   on_publish=sampler.on_publish,
                   should_stop=(lambda: stop_at is not None and time.monotonic() > stop_at))
        if end_alongside is not None:
            end_alongside()
        sampler.finish()

    def _drain(self) -> None:
        """Until the graph is done with the replay (:meth:`GraphMonitor.done`), at most
        ``drain_timeout_s``."""
        drain_until = time.monotonic() + self.options.drain_timeout_s
        self.monitor.restart_quiet_clock()
        while time.monotonic() < drain_until and self.graph.first_exited() is None:
            time.sleep(0.1)
            if self.monitor.done(self.options.settle_s):
                break
        self._raise_if_exited('')

    def _raise_if_exited(self, when: str) -> None:
        exited = self.graph.first_exited()
        if exited is not None:
            raise TlessbotError(f'{exited[0]} exited with code {exited[1]}{when}:\n'
                                f'{"".join(self.output[-20:])}')


def run_graph_on_bag(bag: str | Path, *, config: Path, ros_args: list[str] | None = None,
                     rate: float = 1.0, loop: bool = False, duration_s: float = 0.0,
                     restamp: bool = False, startup_timeout_s: float = 300.0,
                     settle_s: float = 3.0, drain_timeout_s: float = 60.0,
                     lockstep: bool = False, quiet: bool = True,
                     node_prefixes: dict[str, list[str]] | None = None,
                     alongside: Callable[[GraphRunResult], Callable[[], None]] | None = None,
                     part_names: dict[int, str] | None = None,
                     cameras: Sequence[str] | None = None) -> GraphRunResult:
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
        part_names: {id: name} of the parts whose ``/objects/<name>/pose`` to hear (a parts
            folder's, with ``-p parts_path:=...`` in ``ros_args``); None: obj_01 to obj_30.
        cameras: the nodes' ``rig.cameras`` (e.g. ``['side']`` for a bag of one camera);
            None: the config's. The run counts the frames of the main camera (side, or the
            one camera).
    """
    options = GraphRunOptions(rate=rate, loop=loop, duration_s=duration_s, restamp=restamp,
                              startup_timeout_s=startup_timeout_s, settle_s=settle_s,
                              drain_timeout_s=drain_timeout_s, lockstep=lockstep, quiet=quiet,
                              cameras=tuple(cameras) if cameras else None)
    return GraphRun(bag, config=config, options=options, ros_args=ros_args,
                    node_prefixes=node_prefixes, alongside=alongside,
                    part_names=part_names).run()


def _replay_lockstep(node: Any, bag: str, handled: Callable[[], int], on_publish,
                     graph: GraphProcesses, frame_timeout_s: float) -> None:
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
        while handled() < count and time.monotonic() < deadline:
            if graph.first_exited() is not None:
                return
            time.sleep(0.05)
