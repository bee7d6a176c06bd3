"""Killing the stage nodes under ``tlessbot launch`` during a free-running replay (bench
respawn, e2e test): how long until correct poses come again, and whether any pose is wrong.

``tlessbot launch`` runs the stage nodes and restarts them; this process replays the bag in a
loop, restamped, so every frame sent has a stamp of its own and a pose tells whether its frame
was sent before or after a kill. It listens to the poses, the stages' side outputs and
/diagnostics, and kills one node after the other with SIGKILL. Poses are scored against the
bag's ground truth of their own frame (a restamped frame is traced back to the bag through its
log time: simulated bags log every message at its stamp).
"""
from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from tlessbot_ros.conversions.topics import DIAGNOSTICS, classes_topic, labels_topic, pose_topic
from tlessbot_ros.core.common import SIDE, Symmetries
from tlessbot_ros.errors import TlessbotError
from tlessbot_ros.io.ground_truth import GroundTruthInstance, read_ground_truth
from tlessbot_ros.tools.support.bag_scoring import Estimate, score_frame
from tlessbot_ros.tools.support.graph_run import ALL_OBJECT_IDS, FRAME_TOPIC, ReceivedPose
from tlessbot_ros.tools.support.proc_stats import children_by_parent, process_tree
from tlessbot_ros.tools.support.processes import PERCEPTION_NODES
from tlessbot_ros.tools.support.respawn import LAUNCH_STATUS

GRAPH_READY = re.compile(r'\[launch\] graph ready in ([0-9.]+) s')
STAGE_OUTPUTS = {'localiser': labels_topic(SIDE), 'classifier': classes_topic(SIDE)}


@dataclass
class KillResult:
    """One node killed with SIGKILL and what followed (seconds from the kill)."""

    node: str
    pid: int
    killed_ns: int                         # wall clock of the kill (the stamps' clock)
    new_pid: int | None = None
    ready_again_s: float | None = None     # its new process reported ready on /diagnostics
    next_correct_s: float | None = None    # first correct pose of a frame sent after the kill
    wrong_poses: int = 0      # beyond lock-step's, of frames sent from this kill to the next
    late_outputs: int = 0     # the node's results of frames sent before the kill, received
                              # once its new process was ready (stale state: must be 0)
    children: list[int] = field(default_factory=list)  # its child processes when killed
    orphans: list[int] = field(default_factory=list)   # of those, alive after its restart


@dataclass
class RespawnTrial:
    graph_ready_s: float                   # launch's "graph ready in" of this run
    kills: list[KillResult] = field(default_factory=list)
    baseline_wrong: int = 0                # wrong poses before the first kill
    foreign_poses: int = 0    # of stamps this replay never sent: another graph on this
                              # ROS_DOMAIN_ID, or a graph that makes stamps up
    poses: int = 0
    frames_sent: int = 0
    launch_status: dict[str, str] = field(default_factory=dict)   # its last, on /diagnostics
    launch_output: str = ''


def wrong_poses_per_frame(truth: dict[int, list[GroundTruthInstance]],
                          poses: Sequence[ReceivedPose], symmetries: dict[int, Symmetries],
                          frame_of: Callable[[int], int | None] = lambda stamp: stamp
                          ) -> dict[int, int]:
    """{pose stamp: poses of that frame that are not a correct (5 cm / 5 deg) answer to one of
    its parts}: off by more, or matching no part. Poses of parts too little visible to be
    scored count as neither. ``frame_of`` gives the bag stamp of a pose's stamp (None: the
    stamp is no frame that was sent, and every pose of it is wrong)."""
    by_stamp: dict[int, list[Estimate]] = {}
    for pose in poses:
        by_stamp.setdefault(pose.stamp_ns, []).append(
            Estimate(pose.stamp_ns, pose.obj_id, pose.T, pose.frame_id))
    wrong = {}
    for stamp, estimates in by_stamp.items():
        frame = frame_of(stamp)
        if frame is None or frame not in truth:
            wrong[stamp] = len(estimates)
            continue
        matches, false_positives = score_frame(truth[frame], estimates, symmetries)
        wrong[stamp] = len(false_positives) + sum(
            m.estimate is not None and not m.correct for m in matches)
    return wrong


def lockstep_reference(bag: str | Path, *, config: Path, symmetries: dict[int, Symmetries],
                       params: Sequence[str] = ()) -> dict[int, int]:
    """{bag stamp: wrong poses} of a lock-step run of the graph on ``bag`` (every frame
    answered, one after the other): the poses the graph gets wrong without any kill."""
    from tlessbot_ros.tools.support.graph_run import run_graph_on_bag

    run = run_graph_on_bag(bag, config=config, lockstep=True,
                           ros_args=[a for p in params for a in ('-p', p)])
    return wrong_poses_per_frame(read_ground_truth(bag), run.poses, symmetries)


class _Listener:
    """Poses, the stages' side outputs, /diagnostics and the frames sent, as they come."""

    def __init__(self, node) -> None:
        from tlessbot_ros.conversions.cdr import header_stamp_ns
        from tlessbot_ros.conversions.pose import pose_stamped_to_transform
        from tlessbot_ros.nodes.common import RESULT_QOS, message_class

        self.lock = threading.Lock()
        self.poses: list[ReceivedPose] = []
        self.arrivals: dict[int, float] = {}    # id(pose): monotonic arrival
        self.outputs: dict[str, list[tuple[int, float]]] = {n: [] for n in STAGE_OUTPUTS}
        self.ready_at: dict[tuple[str, str], float] = {}   # (node, pid): first ready seen
        self.frames: dict[int, int] = {}        # sent stamp: bag stamp
        self.sent_at: list[float] = []          # monotonic time of every frame sent
        self.launch_status: dict[str, str] = {}

        def on_pose(obj_id: int):
            def callback(msg) -> None:
                T, frame_id, stamp = pose_stamped_to_transform(msg)
                pose = ReceivedPose(stamp, obj_id, T, frame_id, time.time_ns())
                with self.lock:
                    self.poses.append(pose)
                    self.arrivals[id(pose)] = time.monotonic()
            return callback

        def on_output(stage: str):
            def callback(data: bytes) -> None:
                with self.lock:
                    self.outputs[stage].append((header_stamp_ns(data), time.monotonic()))
            return callback

        def on_diagnostics(msg) -> None:
            for status in msg.status:
                values = {kv.key: kv.value for kv in status.values}
                if status.name == LAUNCH_STATUS:
                    self.launch_status = values
                if values.get('ready') == 'true' and 'pid' in values:
                    with self.lock:
                        self.ready_at.setdefault((status.name, values['pid']),
                                                 time.monotonic())

        self._header_stamp_ns = header_stamp_ns
        pose_class = message_class('geometry_msgs/msg/PoseStamped')
        for obj_id in ALL_OBJECT_IDS:
            node.create_subscription(pose_class, pose_topic(obj_id), on_pose(obj_id),
                                     RESULT_QOS)
        image_class = message_class('sensor_msgs/msg/Image')
        for stage, topic in STAGE_OUTPUTS.items():   # raw: only the stamp is read
            node.create_subscription(image_class, topic, on_output(stage), RESULT_QOS,
                                     raw=True)
        node.create_subscription(message_class('diagnostic_msgs/msg/DiagnosticArray'),
                                 DIAGNOSTICS, on_diagnostics, RESULT_QOS)

    def on_publish(self, message) -> None:
        """The replay sent ``message`` (restamped; its log time is the bag's stamp)."""
        if message.topic == FRAME_TOPIC:
            with self.lock:
                self.frames[self._header_stamp_ns(message.raw)] = message.log_time_ns
                self.sent_at.append(time.monotonic())

    def frames_sent_since(self, when: float) -> int:
        with self.lock:
            return sum(t > when for t in self.sent_at)

    def first_correct_after(self, stamp_ns: int, truth, symmetries) -> float | None:
        """Arrival (monotonic) of the first correct pose of a frame stamped after
        ``stamp_ns``, or None."""
        with self.lock:
            poses = [p for p in self.poses if p.stamp_ns > stamp_ns]
            frames = dict(self.frames)
            arrivals = {id(p): self.arrivals[id(p)] for p in poses}
        by_stamp: dict[int, list[tuple[Estimate, float]]] = {}
        for pose in poses:
            by_stamp.setdefault(pose.stamp_ns, []).append(
                (Estimate(pose.stamp_ns, pose.obj_id, pose.T, pose.frame_id),
                 arrivals[id(pose)]))
        firsts = []
        for stamp, entries in by_stamp.items():
            if frames.get(stamp) not in truth:
                continue
            arrival = {id(estimate): t for estimate, t in entries}
            matches, _ = score_frame(truth[frames[stamp]], [e for e, _ in entries], symmetries)
            firsts += [arrival[id(m.estimate)] for m in matches if m.correct]
        return min(firsts, default=None)


def _alive(pid: int) -> bool:
    """The process exists and is no zombie."""
    try:
        return Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()[0] != 'Z'
    except (OSError, IndexError):
        return False


def _node_pid(launch_pid: int, node: str) -> int | None:
    """The pid of launch's child that runs ``node``."""
    for pid in children_by_parent().get(launch_pid, []):
        try:
            argv = Path(f'/proc/{pid}/cmdline').read_bytes().split(b'\0')
        except OSError:
            continue
        if f'tlessbot_ros.nodes.{node}'.encode() in argv and _alive(pid):
            return pid
    return None


def _wait(condition: Callable[[], bool], timeout_s: float, what: str,
          launch: subprocess.Popen, output: list[str]) -> None:
    deadline = time.monotonic() + timeout_s
    while not condition():
        if launch.poll() is not None:
            raise TlessbotError(f'launch exited with code {launch.returncode} while waiting '
                                f'for {what}:\n{"".join(output[-30:])}')
        if time.monotonic() > deadline:
            raise TlessbotError(f'no {what} within {timeout_s:.0f} s:\n{"".join(output[-30:])}')
        time.sleep(0.1)


def run_respawn_trial(bag: str | Path, *, config: Path, symmetries: dict[int, Symmetries],
                      reference_wrong: dict[int, int], nodes: Sequence[str] = PERCEPTION_NODES,
                      params: Sequence[str] = (), frames_between: int = 6,
                      timeout_s: float = 300.0, echo: Callable[[str], None] | None = None
                      ) -> RespawnTrial:
    """Start ``tlessbot launch`` with the stage nodes, replay ``bag`` free-running in a loop,
    and kill each of ``nodes`` in turn once correct poses come.

    Args:
        reference_wrong: {bag stamp: wrong poses lock-step gives for that frame}
            (:func:`wrong_poses_per_frame` of a lock-step run): what is not counted as wrong.
        params: ``NAME:=VALUE`` parameter overrides for every node.
        frames_between: after a node is back (ready, and a correct pose of a frame sent after
            its kill has come), frames sent before the next kill (and before the end).
        timeout_s: the longest wait for any one step (start-up, recovery).
        echo: called with each line launch prints (default: kept quiet).
    """
    import rclpy
    from rclpy.executors import SingleThreadedExecutor

    from tlessbot_ros.nodes.common import init_ros
    from tlessbot_ros.tools.support.replay import replay

    truth = read_ground_truth(bag)
    launch, output = _start_launch(config, params, echo)
    init_ros()
    listener_node = rclpy.create_node('tlessbot_respawn_trial')
    player = rclpy.create_node('tlessbot_respawn_replay')
    listener = _Listener(listener_node)
    executor = SingleThreadedExecutor()
    executor.add_node(listener_node)
    spinner = threading.Thread(target=executor.spin, daemon=True)
    spinner.start()
    stop_replay = threading.Event()
    replayer = threading.Thread(target=replay, args=(player, str(bag)), kwargs=dict(
        loop=True, restamp=True, wait_for_subscribers_s=30.0, on_publish=listener.on_publish,
        should_stop=stop_replay.is_set), daemon=True)
    trial = None
    try:
        _wait(lambda: any(GRAPH_READY.search(line) for line in output), timeout_s,
              'graph ready line from launch', launch, output)
        ready_s = float(next(GRAPH_READY.search(line) for line in output
                             if GRAPH_READY.search(line)).group(1))
        trial = RespawnTrial(graph_ready_s=ready_s)
        replayer.start()
        _wait(lambda: listener.first_correct_after(0, truth, symmetries) is not None, timeout_s,
              'correct pose', launch, output)
        for node in nodes:
            trial.kills.append(_kill_and_recover(node, launch, listener, truth, symmetries,
                                                 frames_between, timeout_s, output))
        stop_replay.set()
        replayer.join(timeout=30.0)
        _drain(listener)
    finally:
        stop_replay.set()
        _stop_launch(launch)
        executor.shutdown()
        if spinner.is_alive():
            spinner.join(timeout=10.0)
        listener_node.destroy_node()
        player.destroy_node()
        rclpy.try_shutdown()
    trial.launch_output = ''.join(output)
    _count_wrong(trial, listener, truth, symmetries, reference_wrong)
    return trial


def _start_launch(config: Path, params: Sequence[str], echo: Callable[[str], None] | None
                  ) -> tuple[subprocess.Popen, list[str]]:
    """``tlessbot launch`` of the perception nodes, and the list its output lines go to."""
    argv = [sys.executable, '-m', 'tlessbot_ros.tools.cli', 'launch', '--config', str(config),
            '--nodes', *PERCEPTION_NODES, *[a for p in params for a in ('-p', p)]]
    launch = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                              bufsize=1, env=dict(os.environ))
    output: list[str] = []

    def pump() -> None:
        for line in launch.stdout:
            output.append(line)
            if echo is not None:
                echo(line.rstrip('\n'))
    threading.Thread(target=pump, daemon=True).start()
    return launch, output


def _stop_launch(launch: subprocess.Popen) -> None:
    """SIGINT to launch (it stops its nodes), SIGKILL after a minute."""
    if launch.poll() is None:
        launch.send_signal(signal.SIGINT)
        try:
            launch.wait(timeout=60)
        except subprocess.TimeoutExpired:
            launch.kill()


def _kill_and_recover(node: str, launch: subprocess.Popen, listener: _Listener, truth,
                      symmetries, frames_between: int, timeout_s: float,
                      output: list[str]) -> KillResult:
    pid = _node_pid(launch.pid, node)
    if pid is None:
        raise TlessbotError(f'launch runs no {node}')
    children = process_tree(pid)[1:]   # its pose workers, if any
    killed_ns, killed_at = time.time_ns(), time.monotonic()
    os.kill(pid, signal.SIGKILL)
    result = KillResult(node, pid, killed_ns, children=children)

    def back() -> bool:
        with listener.lock:
            ready = {p: t for (name, p), t in listener.ready_at.items()
                     if name == node and p != str(pid)}
        if ready and result.ready_again_s is None:
            new_pid, ready_at = min(ready.items(), key=lambda item: item[1])
            result.new_pid, result.ready_again_s = int(new_pid), ready_at - killed_at
        if result.next_correct_s is None:
            arrival = listener.first_correct_after(killed_ns, truth, symmetries)
            if arrival is not None:
                result.next_correct_s = arrival - killed_at
        return result.ready_again_s is not None and result.next_correct_s is not None

    _wait(back, timeout_s, f'recovery of {node}', launch, output)
    ready_again_at = killed_at + result.ready_again_s
    deadline = time.monotonic() + 30.0   # a worker notices its node's death within a second
    while time.monotonic() < deadline and any(_alive(p) for p in children):
        time.sleep(0.1)
    result.orphans = [p for p in children if _alive(p)]
    since = time.monotonic()
    _wait(lambda: listener.frames_sent_since(since) >= frames_between, timeout_s,
          f'{frames_between} frames after {node} came back', launch, output)
    with listener.lock:   # of the frames this replay sent (not another graph's)
        if node in STAGE_OUTPUTS:
            late = [a for s, a in listener.outputs[node]
                    if s <= killed_ns and s in listener.frames]
        else:
            late = [listener.arrivals[id(p)] for p in listener.poses
                    if p.stamp_ns <= killed_ns and p.stamp_ns in listener.frames]
    result.late_outputs = sum(a > ready_again_at for a in late)
    return result


def _drain(listener: _Listener, settle_s: float = 3.0, timeout_s: float = 30.0) -> None:
    """Wait until no pose came for ``settle_s`` (the frames still in the graph are answered)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        with listener.lock:
            last = max(listener.arrivals.values(), default=0.0)
        if time.monotonic() - last > settle_s:
            return
        time.sleep(0.2)


def _count_wrong(trial: RespawnTrial, listener: _Listener, truth, symmetries,
                 reference_wrong: dict[int, int]) -> None:
    """Wrong poses beyond lock-step's, per frame, given to the last kill before the frame was
    sent (before the first kill: the baseline)."""
    frames = listener.frames
    wrong = wrong_poses_per_frame(truth, listener.poses, symmetries, frames.get)
    for stamp, count in wrong.items():
        if stamp not in frames:
            trial.foreign_poses += count
            continue
        excess = max(0, count - reference_wrong.get(frames.get(stamp), 0))
        after = [k for k in trial.kills if k.killed_ns < stamp]
        if after:
            after[-1].wrong_poses += excess
        else:
            trial.baseline_wrong += excess
    trial.launch_status = dict(listener.launch_status)
    trial.poses = len(listener.poses)
    trial.frames_sent = len(listener.sent_at)
