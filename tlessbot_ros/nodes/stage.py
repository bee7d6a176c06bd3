"""The shared skeleton of the perception stage nodes (localiser, classifier, pose_estimator).

A stage node subscribes per-camera topics for the cameras of ``rig.cameras`` (the ``top`` and
``side`` roles, :func:`~tlessbot_ros.core.common.check_camera_roles`), pairs them by
stamp (:class:`~tlessbot_ros.nodes.inputs.TwoViewInputs`), runs one stage, and publishes results
stamped with the source images' stamps. It never dies on bad input: a callback failure is
logged (throttled) and counted. ``/diagnostics`` gets, at 1 Hz, frames processed, failures,
frames dropped by synchronisation, the processing latency, and:

- ``input_age_ms_p50`` / ``_p95``: how old a frame (its newest stamp) is by the node's clock when
  its processing starts, i.e. capture-to-here transport, pairing and waiting. Only frames
  stamped by this clock count: a stamp within ``sync.live_stamp_window_s`` (5 s) of it.
- ``stamp_offset_s``, ``other_clock_frames``: frames whose stamps lie further from the node's
  clock come from another clock: a bag replayed without ``--restamp`` (its recorded stamps, maybe
  years old) or a camera on a host whose clock is not synchronised. Their "age" would be the
  clocks' offset, not a delay, so it is not mixed into the input age; ``stamp_offset_s`` gives the
  node's clock minus the newest stamp of the last such frame, ``other_clock_frames`` how many
  there were. (Replay with ``--restamp`` to measure the input age of a bag.)
- ``time_jumps``, ``last_time_jump_s``: how often the input stamps jumped (a bag looped without
  ``--restamp`` goes back to its start; a camera clock steps) and the last jump's size (s, < 0
  back). At a jump the synchronisation queues are emptied and the age figures start again
  (:mod:`~tlessbot_ros.nodes.inputs`); frames of the new timeline are processed as any other.

On shutdown (Ctrl-C) the frame being processed is finished and published before the node is
destroyed (:func:`~tlessbot_ros.nodes.common.run_node`); a frame that fails because the node is
going down is not reported as an error.

Threading (``sync.worker_thread``, on by default): the executor thread only takes messages and
pairs them; one worker thread runs :meth:`StageNode.process`. A frame that completes while the
worker is busy becomes the single pending frame, and a newer one replaces it, so a slow stage
always starts on the newest frame and its partners are still buffered when its upstream result
comes in.

Parameters (:mod:`~tlessbot_ros.nodes.parameters`): ``rig.CAMERA.*`` and each stage's tuning
are live (``ros2 param set``; applied by the worker thread between frames), ``sync.*`` too
(applied at once); ``rig.cameras``, ``input_qos``, ``input_depth``, ``sync.worker_thread`` and
``sync.executor`` are read-only. ``/diagnostics`` also counts accepted parameter changes and
shows the last.

Restarts (``tlessbot launch`` and ``respawn`` in a launch file start a dead node again): a new
process never publishes anything of a frame that reached the dead one. Everything a frame
passes through lives in the process: the synchronisers' buffers, the pending frame, the pose
workers (they exit with the node). What DDS could hand the new process is bounded too: every
topic is VOLATILE (SENSOR_QOS and RESULT_QOS), so a new subscription gets only samples written
after it matched, never the history a publisher keeps for its old readers; and the
subscriptions exist only once the node is ready, so it sees nothing older than its readiness.
Pairing is by stamp within ``sync.slop_s``, so when an upstream stage comes back, its first
result pairs only with the buffered images of its own frame. ``pid`` on /diagnostics tells the
processes apart (a new pid: the node was restarted).
"""
from __future__ import annotations

import os
import threading
import time
import traceback
from collections import deque
from collections.abc import Callable, Sequence
from concurrent.futures import Future
from functools import partial
from typing import Any

import numpy as np
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from tlessbot_ros.conversions.image import depth_image_to_metres
from tlessbot_ros.conversions.image_cdr import image_from_cdr, image_to_cdr
from tlessbot_ros.conversions.messages import RclpyFactory
from tlessbot_ros.conversions.outcomes import DONE, DROPPED, FAILED, frame_outcome
from tlessbot_ros.conversions.pose import pose_array_to_camera_poses
from tlessbot_ros.conversions.topics import (
    COLOR,
    DEPTH,
    DEPTH_INFO,
    DIAGNOSTICS,
    OBSERVED_RIG,
    camera_topic,
    node_relative,
    outcome_topic,
    relay_topic,
)
from tlessbot_ros.core.common import (
    CAMERA_NAMES,
    TOP,
    CameraMount,
    Rig,
    SyncParams,
    check_camera_roles,
    d415_intrinsics,
    default_rig,
    look_at,
    table_with_box,
)
from tlessbot_ros.core.pipeline import ViewInput
from tlessbot_ros.errors import TlessbotError
from tlessbot_ros.nodes.common import RESULT_QOS, SENSOR_QOS, message_class
from tlessbot_ros.nodes.diagnostics import ERROR, OK, WARN, diagnostic_array
from tlessbot_ros.nodes.inputs import TwoViewInputs, Views, deserialise_views, newest_stamp_ns
from tlessbot_ros.nodes.parameters import AT_ONCE, LiveParameters
from tlessbot_ros.parallel.spare_cpu import SpareCpu, SpareCpuParams

IMAGE = 'sensor_msgs/msg/Image'
CAMERA_INFO = 'sensor_msgs/msg/CameraInfo'
# StageNode.setup_inputs entries of the camera topics: input key -> (type, camera-relative topic)
CAMERA_INPUTS = {'color': (IMAGE, COLOR), 'depth': (IMAGE, DEPTH),
                 'info': (CAMERA_INFO, DEPTH_INFO)}
INPUT_SOURCES = ('localiser', 'cameras')
RIG_SOURCES = ('localiser', 'config')
# The observed rig changes rarely and a stage that starts late must still get the latest.
RIG_QOS = QoSProfile(reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL,
                     history=HistoryPolicy.KEEP_LAST, depth=1)


def camera_inputs(keys: Sequence[str], source: str = 'cameras'
                  ) -> dict[str, tuple[str, Callable[[str], str]]]:
    """``setup_inputs`` entries of the camera inputs ``keys`` (color, depth, info), read from
    the cameras' topics or from the localiser's relay of the frames it admitted."""
    if source not in INPUT_SOURCES:
        raise TlessbotError(f'input_source must be one of {INPUT_SOURCES}, got {source!r}')
    topic = camera_topic if source == 'cameras' else relay_topic
    return {key: (CAMERA_INPUTS[key][0], partial(topic, relative=CAMERA_INPUTS[key][1]))
            for key in keys}


def declare_input_source(node: StageNode) -> str:
    """Declare the read-only ``input_source`` of a stage after the localiser and return it.

    Raises:
        TlessbotError: a source other than :data:`INPUT_SOURCES`.
    """
    source = node.parameters.read_only('input_source', INPUT_SOURCES[0], (
        "where the camera images come from: 'localiser' (its relay of the frames it admitted, "
        '/localiser/<camera>/...: a frame the localiser skipped costs this node nothing) or '
        "'cameras' (every frame of the camera topics)"))
    if source not in INPUT_SOURCES:
        raise TlessbotError(f'input_source must be one of {INPUT_SOURCES}, got {source!r}')
    return source


def follow_observed_rig(node: StageNode) -> str:
    """Declare the read-only ``rig_source`` of a stage after the localiser and, for
    'localiser', subscribe to the camera poses it publishes (:data:`OBSERVED_RIG`) when it
    fuses with a rig refined from the scene: :meth:`StageNode.camera_pose` then gives them."""
    source = node.parameters.read_only('rig_source', RIG_SOURCES[0], (
        "the camera poses this stage reads the views in (table frame, output_frame 'world'): "
        "'localiser': those the localiser publishes on /localiser/rig once it refines the rig "
        "from what the cameras see (rig_refinement.mode 'use'), rig.CAMERA.* until then; "
        "'config': rig.CAMERA.* always"))
    if source not in RIG_SOURCES:
        raise TlessbotError(f'rig_source must be one of {RIG_SOURCES}, got {source!r}')
    if source == 'localiser':
        node.create_subscription(message_class('geometry_msgs/msg/PoseArray'), OBSERVED_RIG,
                                 node._on_observed_rig, RIG_QOS)
    return source


def _stat_text(value: float) -> str:
    """A frame figure for /diagnostics: counts in full (a running count above 999 must not
    become '1.1e+03'), measures to 3 significant digits."""
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    return f'{value:.3g}'


def declare_spare_cpu(node: StageNode) -> SpareCpu:
    """Declare ``parallel.*`` (:class:`~tlessbot_ros.parallel.spare_cpu.SpareCpuParams`, live)
    and return the node's :class:`~tlessbot_ros.parallel.spare_cpu.SpareCpu`: whether a frame's
    work may be split over a second thread or process."""
    spare = SpareCpu()
    spare.params = node.parameters.dataclass(SpareCpuParams(), prefix='parallel.',
                                             apply=partial(setattr, spare, 'params'))
    return spare


def declare_cameras(parameters: LiveParameters) -> tuple[str, ...]:
    """Declare ``rig.cameras`` (read-only; default :data:`~tlessbot_ros.core.common.CAMERA_NAMES`)
    and return it.

    Raises:
        CalibrationError: names other than the two roles the pipeline fuses.
    """
    names = parameters.read_only('rig.cameras', list(CAMERA_NAMES), f'names of the cameras of '
                                 f'the rig: the roles {list(CAMERA_NAMES)}, in any order')
    return check_camera_roles(names)


def declare_extrinsics(parameters: LiveParameters, cameras: Sequence[str],
                       apply: Callable[[str, np.ndarray], None]) -> dict[str, np.ndarray]:
    """Declare ``rig.<camera>.{position_m, look_at_m, up}`` (defaults: the paper's cell) and
    return {camera: T_world_camera}. Intrinsics come from the live CameraInfo instead.

    They are live: a change reaches ``apply(camera, T_world_camera)`` between frames."""
    defaults = default_rig()
    extrinsics = {}
    for camera in cameras:
        names = {key: f'rig.{camera}.{key}' for key in ('position_m', 'look_at_m', 'up')}
        declarations = {
            names['position_m']: ([float(v) for v in defaults[camera].T_world_camera[:3, 3]],
                                  f'{camera} camera position in the world (table) frame, metres'),
            names['look_at_m']: ([0.0, 0.0, 0.0],
                                 f'point the {camera} camera looks at, world frame, metres'),
            names['up']: ([0.0, 1.0, 0.0] if camera == TOP else [0.0, 0.0, 1.0],
                          f'world direction shown at the top of the {camera} image')}
        extrinsics[camera] = parameters.group(
            declarations, build=partial(_camera_pose, names),
            apply=partial(apply, camera))
    return extrinsics


def _camera_pose(names: dict[str, str], values: dict[str, Any]) -> np.ndarray:
    """T_world_camera from a camera's ``position_m``, ``look_at_m`` and ``up`` parameters.

    Raises:
        ValueError: not three finite numbers each, the camera on its target, or ``up`` along
            the viewing direction.
    """
    points = {}
    for key, name in names.items():
        point = np.asarray(values[name], dtype=np.float64)
        if point.shape != (3,) or not np.all(np.isfinite(point)):
            raise ValueError(f'{name} must be three finite numbers [x, y, z], got '
                             f'{list(values[name])}')
        points[key] = point
    if np.linalg.norm(points['look_at_m'] - points['position_m']) < 1e-9:
        raise ValueError(f'{names["position_m"]} and {names["look_at_m"]} coincide: the camera '
                         'must look at a point away from it')
    try:
        return look_at(points['position_m'], points['look_at_m'], points['up'])
    except ValueError as error:
        raise ValueError(f'{names["up"]}: {error}') from None


def input_profile(input_qos: str, depth: int) -> QoSProfile:
    """A stage's subscription QoS: the reliability of ``input_qos`` ('sensor_data' or
    'reliable'), VOLATILE (a new subscriber gets no sample written before it matched), and
    ``depth`` samples of history."""
    base = SENSOR_QOS if input_qos == 'sensor_data' else RESULT_QOS
    return QoSProfile(reliability=base.reliability, durability=base.durability,
                      history=HistoryPolicy.KEEP_LAST, depth=max(1, int(depth)))


def rig_with_intrinsics(extrinsics: dict[str, np.ndarray], intrinsics: dict[str, Any]) -> Rig:
    """A Rig from configured extrinsics and the intrinsics of the current CameraInfos."""
    return Rig(cameras={c: CameraMount(c, intrinsics[c], extrinsics[c]) for c in intrinsics})


class StageNode(Node):
    """Base of the three perception nodes. Subclasses call :meth:`setup_inputs` and implement
    :meth:`process`."""

    def __init__(self, name: str, *, after_localiser: bool = False,
                 pauses_inputs: bool = False, **kwargs: Any) -> None:
        """``after_localiser``: a stage that may read the localiser's relay of the frames it
        admitted; it declares ``input_source`` (:attr:`input_source`; the localiser itself
        reads the cameras). ``pauses_inputs``: a stage whose :meth:`input_gate` pauses its
        subscriptions (the entrance); its ``sync.executor`` defaults to 'single_threaded',
        which leaves the paused messages in DDS (:class:`~.inputs.TwoViewInputs`)."""
        self._created = time.monotonic()
        super().__init__(name, **kwargs)
        self.ready = threading.Event()
        self.ready_after_s: float | None = None   # from construction to ready
        self.warm_up_s: float | None = None
        self.parameters = LiveParameters(self)
        self.cameras = declare_cameras(self.parameters)
        self.extrinsics = declare_extrinsics(self.parameters, self.cameras,
                                             self._apply_extrinsics)
        self.input_source = declare_input_source(self) if after_localiser else 'cameras'
        # Behind the relay the localiser has already confirmed every time jump (and dropped
        # strays), so a step back counts at once; on the camera topics it must be confirmed.
        sync_defaults = SyncParams(executor='single_threaded') if pauses_inputs else SyncParams()
        self.sync_params = self.parameters.dataclass(
            sync_defaults.behind_relay() if self.input_source == 'localiser' else sync_defaults,
            prefix='sync.', when=AT_ONCE, read_only=('worker_thread', 'executor'),
            apply=self._apply_sync)
        self.input_qos = self.parameters.read_only('input_qos', 'sensor_data', (
            "QoS of the subscriptions: 'sensor_data' (best effort, the ROS convention for "
            "camera streams) or 'reliable' (no loss of large images under CPU load)"))
        self.input_depth = self.parameters.read_only('input_depth', 2, (
            'History depth of each subscription: a node that falls behind drops the older '
            'frames instead of queueing them (latency stays bounded)'))
        if self.input_qos not in ('sensor_data', 'reliable'):
            raise TlessbotError(f"input_qos must be 'sensor_data' or 'reliable', got "
                                f'{self.input_qos!r}')
        self.frames = 0
        self.failures = 0
        self.rate_dropped = 0   # complete frames skipped by sync.max_rate_hz
        self.entrance_dropped = 0   # complete frames refused by admit() (backpressure)
        self.busy_dropped = 0   # complete frames replaced by a newer one while the worker ran
        self._last_start = -float('inf')
        self._pending: Views | None = None
        # frames released together at a time jump (at most jump_confirmations + 1 at a time)
        self._held_frames: deque[Views] = deque()
        self._busy = False
        self._wakeup = threading.Condition()
        self._stopping = False
        self._worker: threading.Thread | None = None
        self._jobs: deque[tuple[Callable[[], Any], Future]] = deque()   # see on_frame_thread
        self.last_error = ''
        self._latencies_ms: deque[float] = deque(maxlen=100)
        self._input_ages_ms: deque[float] = deque(maxlen=100)
        self.other_clock_frames = 0   # frames stamped by another clock (input age not measured)
        self._stamp_offset_s: float | None = None
        self._stats: dict[str, float] = {}
        self._inputs: TwoViewInputs | None = None
        self.observed_rig: dict[str, np.ndarray] | None = None   # from /localiser/rig
        self._diagnostics = self.create_publisher(
            message_class('diagnostic_msgs/msg/DiagnosticArray'), DIAGNOSTICS, RESULT_QOS)
        self.create_timer(1.0, self._publish_diagnostics)
        # What became of each frame this stage took, for the entrance's backpressure.
        self._outcomes = self.create_publisher(message_class('std_msgs/msg/Header'),
                                               node_relative(outcome_topic(name)), RESULT_QOS)
        self._outcome_factory = RclpyFactory()
        if self.sync_params.worker_thread:
            self._worker = threading.Thread(target=self._work, name=f'{name}_worker',
                                            daemon=True)
            self._worker.start()

    @property
    def executor_kind(self) -> str:
        """The executor :func:`~tlessbot_ros.nodes.common.run_node` spins this node with
        (``sync.executor``)."""
        return self.sync_params.executor

    def start_when_ready(self, warm_up: Callable[[], None],
                         topics: dict[str, tuple[str, Callable[[str], str]]]) -> None:
        """Run ``warm_up`` on the frame thread (:meth:`on_frame_thread`), then subscribe
        ``topics`` and report ready.

        The executor spins meanwhile, so ``/diagnostics`` says WARN 'starting' until the stage
        is ready and OK with ``ready: true`` and the warm-up time after. Subscribing only once
        ready means a replay that waits for subscribers starts when this node can take frames.
        A warm-up that fails leaves the node reporting ERROR with the reason, unsubscribed.
        """
        def run() -> None:
            started = time.monotonic()
            try:
                warm_up()
            except Exception as error:  # reported, never raised into a dead thread
                self.last_error = f'warm-up failed: {type(error).__name__}: {error}'
                with self._wakeup:
                    if not self._stopping:
                        self.get_logger().error(self.last_error)
                        self.get_logger().debug(traceback.format_exc())
                        self._publish_diagnostics()
                return
            # Under the lock destroy_node takes first: a node shut down meanwhile (Ctrl-C)
            # subscribes and reports nothing, and none is torn down halfway through this.
            with self._wakeup:
                if self._stopping:
                    return
                self.setup_inputs(topics)
                now = time.monotonic()
                self.warm_up_s, self.ready_after_s = now - started, now - self._created
                self.ready.set()
                self.get_logger().info(f'ready {self.ready_after_s:.1f} s after start '
                                       f'(warm-up {self.warm_up_s:.1f} s)')
                self._publish_diagnostics()

        def report(done: Future) -> None:   # subscribing failed: said, as a warm-up failure
            if not done.cancelled() and done.exception() is not None:
                error = done.exception()
                self.last_error = f'start-up failed: {type(error).__name__}: {error}'
                self.get_logger().error(self.last_error)

        self.on_frame_thread(run).add_done_callback(report)

    def on_frame_thread(self, job: Callable[[], Any]) -> Future:
        """Run ``job`` on the thread that processes this stage's frames, before the next
        frame; the Future gives its result (cancelled if the node is destroyed first).

        The warm-up runs there so that the first frame costs what the hundredth does: the
        thread's own memory grows and stays with it (glibc gives each thread its own malloc
        arena; OpenCV keeps per-thread buffers). Warmed on another thread, the localiser's
        first 4-6 frames took 1.5-2.5 x the steady time, in CPU as well as wall time, with
        ~2400 page faults on the first (docs/bench/first-frame.md). Without a worker thread
        (``sync.worker_thread`` false) frames run on the executor's thread, which a job
        cannot borrow: the job then runs on a thread of its own.
        """
        done: Future = Future()
        if self._worker is None:
            threading.Thread(target=_run_job, args=(job, done), daemon=True,
                             name=f'{self.get_name()}_job').start()
            return done
        with self._wakeup:
            if self._stopping:
                done.cancel()
            else:
                self._jobs.append((job, done))
                self._wakeup.notify_all()
        return done

    def warm_up_frame(self, backgrounds: dict[str, Any] | None = None
                      ) -> tuple[dict[str, ViewInput], dict[str, np.ndarray]]:
        """A synthetic two-view frame for the warm-up: per camera, a box on the table seen
        from the configured extrinsics at the D415's 640x480 (the background's size when one
        is set), and its (H, W) uint16 instance labels (the box is instance 1)."""
        # the depth conversion's kernel, on a depth image read as one arrives (read-only)
        depth_image_to_metres(image_from_cdr(image_to_cdr(np.ones((2, 4), np.uint16), '16UC1')))
        views, labels = {}, {}
        for camera in self.cameras:
            background = (backgrounds or {}).get(camera)   # a BackgroundModel or None
            shape = (480, 640) if background is None else background.rgb.shape[:2]
            intrinsics = d415_intrinsics(shape[1], shape[0])
            rgb, depth, box = table_with_box(intrinsics, self.extrinsics[camera])
            views[camera] = ViewInput(rgb=rgb, depth_m=depth, intrinsics=intrinsics,
                                      T_world_camera=self.extrinsics[camera],
                                      background=background)
            labels[camera] = box.astype(np.uint16)
        return views, labels

    def wait_ready(self, timeout_s: float = 300.0) -> bool:
        """Block until the stage is ready (in-process tests and tools); False on timeout."""
        return self.ready.wait(timeout_s)

    def setup_inputs(self, topics: dict[str, tuple[str, Callable[[str], str]]]) -> None:
        """Subscribe ``{key: (ROS type name, camera -> topic name)}`` for both cameras."""
        self._inputs = TwoViewInputs(
            self, {k: (message_class(t), topic) for k, (t, topic) in topics.items()},
            self.cameras, self.sync_params, self._on_views,
            qos=input_profile(self.input_qos, self.input_depth), on_time_jump=self._on_time_jump,
            gate=self.input_gate(), pause_in_dds=self.executor_kind == 'single_threaded')

    def input_gate(self) -> Callable[[], bool] | None:
        """Hook: a function that says whether the inputs are read now (the entrance pauses
        them while it is full, :class:`~tlessbot_ros.nodes.inputs.TwoViewInputs`); None: they
        always are."""
        return None

    def _on_time_jump(self, jump_ns: int) -> None:
        """The input stamps jumped (the queues are empty already): ages start again. The
        clocks' offset is kept until the next frame measures it: /diagnostics published in
        between would otherwise lose it (a test reading the last status saw it missing)."""
        self._input_ages_ms.clear()
        self.get_logger().warning(
            f'input stamps jumped {"back" if jump_ns < 0 else "forward"} by '
            f'{abs(jump_ns) / 1e9:.3f} s (a bag replayed in a loop without --restamp, or a '
            'clock step): synchronisation restarted', throttle_duration_sec=10.0)

    def _apply_sync(self, params: SyncParams) -> None:
        """New ``sync.*`` (executor thread, as the subscriptions' callbacks): the rate cap
        holds from the next frame; new thresholds restart the pairing."""
        with self._wakeup:   # setup_inputs (warm-up thread) reads them under this lock
            self.sync_params = params
            if self._inputs is not None:
                self._inputs.reconfigure(params)

    def _apply_extrinsics(self, camera: str, T_world_camera: np.ndarray) -> None:
        self.extrinsics = {**self.extrinsics, camera: T_world_camera}

    def camera_pose(self, camera: str) -> np.ndarray:
        """``T_world_camera`` of a camera: the localiser's observed rig when this stage
        follows it (:func:`follow_observed_rig`) and one came, else ``rig.CAMERA.*``."""
        observed = self.observed_rig
        return observed[camera] if observed is not None else self.extrinsics[camera]

    def _on_observed_rig(self, msg: Any) -> None:
        try:
            poses = pose_array_to_camera_poses(msg, names=CAMERA_NAMES)
        except ValueError as error:
            self.get_logger().warning(f'{OBSERVED_RIG}: {error}', throttle_duration_sec=5.0)
            return
        self.observed_rig = poses   # one reference swap: a frame sees the old or the new
        self.get_logger().info(f'camera poses from {OBSERVED_RIG} (the rig the localiser '
                               'observes) in use')

    def _on_views(self, views: Views, held: bool = False) -> None:
        """A complete two-view frame: hand it to the worker (or process it here without one).
        ``held`` frames (held while a time jump waited for its confirmation, then released
        together) are all taken and processed in order: a looped bag loses none of them."""
        max_rate = self.sync_params.max_rate_hz
        now = time.perf_counter()
        if not held and max_rate > 0 and now - self._last_start < 1.0 / max_rate:
            self.rate_dropped += 1
            return
        if not self.admit(views, held=held):
            return
        self._last_start = now
        self.take_frame(views, held=held)

    def take_frame(self, views: Views, *, held: bool = False) -> None:
        """Take an admitted frame: tell :meth:`on_admitted`, then hand it to the worker (the
        frame it replaces, still waiting for the worker, is dropped) or process it here."""
        self.on_admitted(views)
        if self._worker is None:
            self.parameters.apply_pending()
            self._process_safely(views)
            return
        with self._wakeup:
            replaced = None
            if held:
                self._held_frames.append(views)
            else:
                replaced, self._pending = self._pending, views
            if replaced is not None:
                self.busy_dropped += 1
            self._wakeup.notify()
        if replaced is not None:
            self.report_outcome(replaced, DROPPED)

    def admit(self, views: Views, *, held: bool = False) -> bool:
        """Whether to take a complete frame now (after ``sync.max_rate_hz``); the entrance of
        the graph overrides it to apply backpressure (``held`` frames are always taken, see
        :meth:`_on_views`) and counts in ``entrance_dropped`` the frames it refuses for good
        (counted, not reported: they never entered the graph)."""
        return True

    def on_admitted(self, views: Views) -> None:
        """Hook: a complete frame was taken (before it waits for the worker)."""

    def report_outcome(self, views: Views, outcome: str) -> None:
        """Publish what became of a frame (``done``, ``dropped``, ``failed``) on
        ``/<node>/frames`` and tell :meth:`on_outcome`."""
        stamp_ns = newest_stamp_ns(views)
        if stamp_ns is None:
            return
        self.on_outcome(stamp_ns, outcome)
        try:
            self._outcomes.publish(frame_outcome(stamp_ns, outcome, self._outcome_factory))
        except Exception:  # shutting down: the context is gone, nobody listens any more
            pass

    def on_outcome(self, stamp_ns: int, outcome: str) -> None:
        """Hook: this stage finished with frame ``stamp_ns`` (see :meth:`report_outcome`)."""

    def _work(self) -> None:
        while True:
            with self._wakeup:
                while (self._pending is None and not self._held_frames and not self._jobs
                       and not self._stopping):
                    self._wakeup.wait()
                if self._stopping:
                    return
                if self._jobs:   # the warm-up, a tool's call: before any frame
                    job, done = self._jobs.popleft()
                else:
                    job = None
                    if self._held_frames:   # older than any pending frame: first, in order
                        views = self._held_frames.popleft()
                    else:
                        views, self._pending = self._pending, None
                    self._busy = True
            if job is not None:
                _run_job(job, done)
                continue
            self.parameters.apply_pending()   # between frames: a frame sees all or nothing
            self._process_safely(views)

    def wait_idle(self, timeout_s: float = 10.0) -> bool:
        """Block until no frame is pending (tests, tools); False on timeout."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            with self._wakeup:
                if self._pending is None and not self._held_frames and not self._busy:
                    return True
            time.sleep(0.005)
        return False

    def destroy_node(self) -> None:
        with self._wakeup:
            self._stopping = True
            for _, done in self._jobs:
                done.cancel()
            self._jobs.clear()
            self._wakeup.notify_all()
        # A node not ready yet has no frame to finish: Ctrl-C during the warm-up does not wait
        # for it (it stops at its end, seeing _stopping).
        if (self._worker is not None and self._worker is not threading.current_thread()
                and self.ready.is_set()):
            self._worker.join(timeout=30.0)
        super().destroy_node()

    def _process_safely(self, views: Views) -> None:
        start = time.perf_counter()
        try:
            stamp_ns = newest_stamp_ns(views)
            if stamp_ns is not None:
                self._record_input_age(stamp_ns)
            self.process(deserialise_views(views))
            self.frames += 1
            outcome = DONE
        except Exception as error:  # a bad frame must never take the node down
            if self._stopping or not self.context.ok():   # cut short by the shutdown
                self.get_logger().debug(f'frame left unfinished at shutdown: {error}')
                return
            outcome = FAILED
            self.failures += 1
            self.last_error = f'{type(error).__name__}: {error}'
            self.get_logger().error(f'frame skipped: {self.last_error}',
                                    throttle_duration_sec=5.0)
            self.get_logger().debug(traceback.format_exc())
        finally:
            self._busy = False
            self._latencies_ms.append(1e3 * (time.perf_counter() - start))
        self.report_outcome(views, outcome)

    def _record_input_age(self, stamp_ns: int) -> None:
        """The frame's age by the node's clock, if it was stamped by that clock (see the module
        docstring); else the clocks' offset."""
        offset_ns = self.get_clock().now().nanoseconds - stamp_ns
        if abs(offset_ns) <= self.sync_params.live_stamp_window_s * 1e9:
            self._input_ages_ms.append(offset_ns / 1e6)
        else:
            self.other_clock_frames += 1
            self._stamp_offset_s = offset_ns / 1e9

    def process(self, views: Views) -> None:
        """Handle one synchronised two-view frame (``{camera: {key: msg}}``)."""
        raise NotImplementedError

    def record_stats(self, stats: dict[str, float]) -> None:
        """Figures of the last frame shown on /diagnostics (stage times, counts, fitness)."""
        self._stats = dict(stats)

    def extra_status(self) -> tuple[str, dict[str, str]]:
        """A stage's own /diagnostics warning ('' for none; it makes an OK status WARN with
        this message) and values (executor thread: return a snapshot)."""
        return '', {}

    def _publish_diagnostics(self) -> None:
        dropped = (self._inputs.dropped if self._inputs else 0) + self.rate_dropped + \
            self.busy_dropped + self.entrance_dropped
        level = OK if not self.failures else (ERROR if self.frames == 0 else WARN)
        readiness = {'ready': 'true', 'ready_after_s': f'{self.ready_after_s:.2f}',
                     'warm_up_s': f'{self.warm_up_s:.2f}'} if self.ready.is_set() else \
            {'ready': 'false', 'starting_s': f'{time.monotonic() - self._created:.1f}'}
        if not self.ready.is_set():
            level = ERROR if self.last_error else WARN
        values = {**readiness, 'pid': os.getpid(), 'frames': self.frames,
                  'failures': self.failures, 'dropped': dropped,
                  **_percentiles('latency_ms', self._latencies_ms),
                  **_percentiles('input_age_ms', self._input_ages_ms),
                  **self._clock_values(),
                  'zero_stamps': self._inputs.zero_stamps if self._inputs else 0,
                  'malformed': self._inputs.malformed if self._inputs else 0,
                  **({'unread_frames_est': self._inputs.unread_estimate}
                     if self._inputs and self._inputs.gated else {}),
                  **{k: _stat_text(v) for k, v in self._stats.items()}}
        if self.parameters.changes:
            values.update(parameter_changes=self.parameters.changes,
                          last_parameter_change=self.parameters.last_change)
        if self.last_error:
            values['last_error'] = self.last_error
        warning, extra = self.extra_status()
        values.update(extra)
        message = 'ok' if level == OK else (self.last_error or 'starting')
        if warning and level == OK:
            level, message = WARN, warning
        self._diagnostics.publish(diagnostic_array(
            self.get_clock().now().to_msg(), self.get_name(), level, message, values))

    def _clock_values(self) -> dict[str, str | int]:
        """/diagnostics keys on the input stamps' clock: other clocks, time jumps."""
        values: dict[str, str | int] = {}
        if self.other_clock_frames:
            values['other_clock_frames'] = self.other_clock_frames
        if self._stamp_offset_s is not None:
            values['stamp_offset_s'] = f'{self._stamp_offset_s:.3f}'
        jumps = self._inputs.jumps if self._inputs else None
        values['time_jumps'] = jumps.count if jumps else 0
        if jumps and jumps.count:
            values['last_time_jump_s'] = f'{jumps.last_jump_ns / 1e9:.3f}'
        return values


def _percentiles(name: str, values: deque[float]) -> dict[str, str]:
    """``{name_p50, name_p95}`` of recent values, formatted (empty before the first)."""
    if not values:
        return {}
    p50, p95 = np.percentile(np.asarray(values), [50, 95])
    return {f'{name}_p50': f'{p50:.1f}', f'{name}_p95': f'{p95:.1f}'}


def _run_job(job: Callable[[], Any], done: Future) -> None:
    """Run ``job`` into ``done`` (a job cancelled meanwhile is skipped)."""
    if not done.set_running_or_notify_cancel():
        return
    try:
        done.set_result(job())
    except BaseException as error:  # the caller of on_frame_thread gets it from the Future
        done.set_exception(error)
