"""The shared skeleton of the perception stage nodes (localiser, classifier, pose_estimator).

A stage node subscribes per-camera topics for the cameras of ``rig.cameras`` (the ``top`` and
``side`` roles, or one camera: :func:`~tlessbot_ros.core.common.check_camera_roles`), pairs
them by stamp (:class:`~tlessbot_ros.nodes.inputs.TwoViewInputs`), runs one stage, and
publishes results stamped with the source images' stamps. It never dies on bad input: a
callback failure is logged (throttled) and counted.

:class:`StageNode` wires small parts it holds; a stage implements :meth:`StageNode.process`
and calls :meth:`StageNode.start_when_ready`:

- :class:`~tlessbot_ros.nodes.frame_worker.FrameWorker` (``worker``): the frame thread, the
  pending frame, the warm-up and jobs on that thread.
- :class:`~tlessbot_ros.nodes.stage_status.StageStatus` (``status``): counters, figures and
  readiness, published on ``/diagnostics`` at 1 Hz (the keys are listed there).
- :class:`~tlessbot_ros.nodes.admission.RateCap` (``rate_cap``, ``sync.max_rate_hz``) and, at
  the graph's entrance only, :class:`~tlessbot_ros.nodes.admission.Entrance` (``entrance``):
  which complete frames are taken; the entrance is also the inputs' gate.
- ``relay`` (the entrance only): passes each taken frame on to the later stages.
- the declarations every stage shares: :mod:`~tlessbot_ros.nodes.stage_config`.

On shutdown (Ctrl-C) the frame being processed is finished and published before the node is
destroyed (:func:`~tlessbot_ros.nodes.spin.run_node`); a frame that fails because the node is
going down is not reported as an error. What became of each frame taken (``done``,
``dropped``, ``failed``) goes out on ``/<node>/frames`` for the entrance's backpressure.

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

import time
import traceback
from collections.abc import Callable
from concurrent.futures import Future
from typing import Any

import numpy as np
from rclpy.node import Node

from tlessbot_ros.conversions.image import depth_image_to_metres
from tlessbot_ros.conversions.image_cdr import image_from_cdr, image_to_cdr
from tlessbot_ros.conversions.messages import RclpyFactory, message_class
from tlessbot_ros.conversions.outcomes import DONE, DROPPED, FAILED, frame_outcome
from tlessbot_ros.conversions.pose import pose_array_to_camera_poses
from tlessbot_ros.conversions.topics import DIAGNOSTICS, OBSERVED_RIG, node_relative, outcome_topic
from tlessbot_ros.core.common import CAMERA_NAMES, SyncParams, d415_intrinsics, table_with_box
from tlessbot_ros.core.label_views import view_order
from tlessbot_ros.core.pipeline import ViewInput
from tlessbot_ros.nodes.admission import Entrance, RateCap
from tlessbot_ros.nodes.diagnostics import diagnostic_array
from tlessbot_ros.nodes.frame_worker import FrameWorker
from tlessbot_ros.nodes.inputs import TwoViewInputs, Views, deserialise_views, newest_stamp_ns
from tlessbot_ros.nodes.parameters import AT_ONCE, LiveParameters
from tlessbot_ros.nodes.qos import RESULT_QOS
from tlessbot_ros.nodes.stage_config import (  # noqa: F401 (the stages import them from here)
    CAMERA_INFO,
    CAMERA_INPUTS,
    IMAGE,
    INPUT_SOURCES,
    RIG_QOS,
    RIG_SOURCES,
    camera_inputs,
    declare_cameras,
    declare_extrinsics,
    declare_input_qos,
    declare_input_source,
    declare_spare_cpu,
    follow_observed_rig,
    input_profile,
    rig_with_intrinsics,
)
from tlessbot_ros.nodes.stage_status import StageStatus, stat_text

_stat_text = stat_text   # its name before stage_status.py (tools' tests import it from here)


def _read_out(part: str, name: str) -> property:
    """A read-only attribute of the node that is its ``part``'s ``name`` (tests, tools)."""
    return property(lambda node: getattr(getattr(node, part), name))


class StageNode(Node):
    """Base of the three perception nodes: the parts they share, wired. A stage implements
    :meth:`process` and calls :meth:`start_when_ready`."""

    def __init__(self, name: str, *, after_localiser: bool = False,
                 pauses_inputs: bool = False, **kwargs: Any) -> None:
        """``after_localiser``: a stage that may read the localiser's relay of the frames it
        admitted; it declares ``input_source`` (:attr:`input_source`; the localiser itself
        reads the cameras). ``pauses_inputs``: a stage whose :attr:`entrance` pauses its
        subscriptions; its ``sync.executor`` defaults to 'single_threaded', which leaves the
        paused messages in DDS (:class:`~.inputs.TwoViewInputs`)."""
        self.status = StageStatus()
        super().__init__(name, **kwargs)
        self.ready = self.status.ready
        self.parameters = LiveParameters(self)
        self.cameras = declare_cameras(self.parameters)
        self.main_camera = view_order(self.cameras)[0]   # side, or the rig's one camera
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
        self.input_qos, self.input_depth = declare_input_qos(self.parameters)
        self.rate_cap = RateCap()
        self.entrance: Entrance | None = None   # the graph's entrance holds one (localiser)
        self.relay: Any = None   # .publish(views) of each frame taken (localiser)
        self._inputs: TwoViewInputs | None = None
        self.observed_rig: dict[str, np.ndarray] | None = None   # from /localiser/rig
        self._diagnostics = self.create_publisher(
            message_class('diagnostic_msgs/msg/DiagnosticArray'), DIAGNOSTICS, RESULT_QOS)
        self.create_timer(1.0, self._publish_diagnostics)
        # What became of each frame this stage took, for the entrance's backpressure.
        self._outcomes = self.create_publisher(message_class('std_msgs/msg/Header'),
                                               node_relative(outcome_topic(name)), RESULT_QOS)
        self._outcome_factory = RclpyFactory()
        self.worker = FrameWorker(f'{name}_worker', self._process_frame,
                                  self.parameters.apply_pending,
                                  threaded=self.sync_params.worker_thread)

    # Read-outs of the parts (tests and tools read them on the node).
    frames = _read_out('status', 'frames')
    failures = _read_out('status', 'failures')
    last_error = _read_out('status', 'last_error')
    busy_dropped = _read_out('status', 'busy_dropped')
    other_clock_frames = _read_out('status', 'other_clock_frames')
    ready_after_s = _read_out('status', 'ready_after_s')
    warm_up_s = _read_out('status', 'warm_up_s')
    _stats = _read_out('status', 'stats')
    _input_ages_ms = _read_out('status', 'input_ages_ms')
    _stamp_offset_s = _read_out('status', 'stamp_offset_s')
    rate_dropped = _read_out('rate_cap', 'dropped')
    _worker = _read_out('worker', 'thread')
    _busy = _read_out('worker', 'busy')

    @property
    def entrance_dropped(self) -> int:
        """Complete frames the entrance refused for good (0 without one)."""
        return 0 if self.entrance is None else self.entrance.dropped

    @property
    def executor_kind(self) -> str:
        """The executor :func:`~tlessbot_ros.nodes.spin.run_node` spins this node with
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
        def ready(warm_up_s: float) -> None:   # under the worker's lock, not stopping
            self.setup_inputs(topics)
            self.status.set_ready(warm_up_s)
            self.get_logger().info(f'ready {self.ready_after_s:.1f} s after start '
                                   f'(warm-up {self.warm_up_s:.1f} s)')
            self._publish_diagnostics()

        self.worker.when_warm(warm_up, ready, self._start_failed)

    def _start_failed(self, message: str, trace: str) -> None:
        self.status.last_error = message
        if not self.worker.stopping:
            self.get_logger().error(message)
            self.get_logger().debug(trace)
            self._publish_diagnostics()

    def on_frame_thread(self, job: Callable[[], Any]) -> Future:
        """Run ``job`` on the thread that processes this stage's frames, before the next
        frame; the Future gives its result (cancelled if the node is destroyed first).

        The warm-up runs there so that the first frame costs what the hundredth does: the
        thread's own memory grows and stays with it (glibc gives each thread its own malloc
        arena; OpenCV keeps per-thread buffers; docs/bench/first-frame.md). Without a worker
        thread (``sync.worker_thread`` false) the job runs on a thread of its own.
        """
        return self.worker.on_frame_thread(job)

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

    def wait_idle(self, timeout_s: float = 10.0) -> bool:
        """Block until no frame is pending (tests, tools); False on timeout."""
        return self.worker.wait_idle(timeout_s)

    def setup_inputs(self, topics: dict[str, tuple[str, Callable[[str], str]]]) -> None:
        """Subscribe ``{key: (ROS type name, camera -> topic name)}`` for both cameras; the
        entrance, if any, is their gate."""
        self._inputs = TwoViewInputs(
            self, {k: (message_class(t), topic) for k, (t, topic) in topics.items()},
            self.cameras, self.sync_params, self._on_views,
            qos=input_profile(self.input_qos, self.input_depth), on_time_jump=self._on_time_jump,
            gate=None if self.entrance is None else self.entrance.is_open,
            pause_in_dds=self.executor_kind == 'single_threaded')

    def reopen_inputs(self, keep_newest: bool = True) -> None:
        """Read what waited in the paused inputs (:meth:`~.inputs.TwoViewInputs.reopen`)."""
        if self._inputs is not None:
            self._inputs.reopen(keep_newest=keep_newest)

    def _on_time_jump(self, jump_ns: int) -> None:
        """The input stamps jumped (the queues are empty already): ages and the frames open
        at the entrance start again."""
        self.status.time_jumped()
        self.get_logger().warning(
            f'input stamps jumped {"back" if jump_ns < 0 else "forward"} by '
            f'{abs(jump_ns) / 1e9:.3f} s (a bag replayed in a loop without --restamp, or a '
            'clock step): synchronisation restarted', throttle_duration_sec=10.0)
        if self.entrance is not None:
            self.entrance.time_jumped()

    def _apply_sync(self, params: SyncParams) -> None:
        """New ``sync.*`` (executor thread, as the subscriptions' callbacks): the rate cap
        holds from the next frame; new thresholds restart the pairing."""
        with self.worker.lock:   # setup_inputs (warm-up thread) reads them under this lock
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

    def on_observed_rig(self, msg: Any) -> None:
        """The camera poses the localiser observes (:data:`OBSERVED_RIG`) came."""
        try:
            poses = pose_array_to_camera_poses(msg, names=CAMERA_NAMES)
        except ValueError as error:
            self.get_logger().warning(f'{OBSERVED_RIG}: {error}', throttle_duration_sec=5.0)
            return
        self.observed_rig = poses   # one reference swap: a frame sees the old or the new
        self.get_logger().info(f'camera poses from {OBSERVED_RIG} (the rig the localiser '
                               'observes) in use')

    def _on_views(self, views: Views, held: bool = False) -> None:
        """A complete two-view frame: take it if the rate cap and the entrance admit it.
        ``held`` frames (held while a time jump waited for its confirmation, then released
        together) are all taken and processed in order: a looped bag loses none of them."""
        now = time.perf_counter()
        if not self.rate_cap.allows(self.sync_params.max_rate_hz, now, held=held):
            return
        if not self.admit(views, held=held):
            return
        self.rate_cap.taken(now)
        self.take_frame(views, held=held)

    def admit(self, views: Views, *, held: bool = False) -> bool:
        """Whether the entrance, if this node is one, takes a complete frame now
        (:meth:`~tlessbot_ros.nodes.admission.Entrance.admit`)."""
        return self.entrance is None or self.entrance.admit(views, held=held)

    def take_frame(self, views: Views, *, held: bool = False) -> None:
        """Take an admitted frame: relay it (the entrance), then hand it to the worker (the
        frame it replaces, still waiting for the worker, is dropped) or process it here."""
        if self.relay is not None:
            self.relay.publish(views)
        replaced = self.worker.submit(views, held=held)
        if replaced is not None:
            self.status.busy_dropped += 1
            self.report_outcome(replaced, DROPPED)

    def report_outcome(self, views: Views, outcome: str) -> None:
        """Publish what became of a frame (``done``, ``dropped``, ``failed``) on
        ``/<node>/frames`` and tell the entrance, if any."""
        stamp_ns = newest_stamp_ns(views)
        if stamp_ns is None:
            return
        if self.entrance is not None:
            self.entrance.finished_here(stamp_ns, outcome)
        try:
            self._outcomes.publish(frame_outcome(stamp_ns, outcome, self._outcome_factory))
        except Exception:  # shutting down: the context is gone, nobody listens any more
            pass

    def destroy_node(self) -> None:
        # A node not ready yet has no frame to finish: Ctrl-C during the warm-up does not wait
        # for it here (it stops at its end, seeing the worker stopping); an interpreter's exit
        # does (nodes/exit_wait.py).
        self.worker.stop(join=self.ready.is_set())
        super().destroy_node()

    def _process_frame(self, views: Views) -> None:
        """Process one frame on the frame thread, count it and report its outcome; a bad
        frame is logged (throttled), never raised."""
        start = time.perf_counter()
        try:
            stamp_ns = newest_stamp_ns(views)
            if stamp_ns is not None:
                self.status.record_input_age(self.get_clock().now().nanoseconds - stamp_ns,
                                             self.sync_params.live_stamp_window_s)
            self.process(deserialise_views(views))
            self.status.frames += 1
            outcome = DONE
        except Exception as error:  # a bad frame must never take the node down
            if self.worker.stopping or not self.context.ok():   # cut short by the shutdown
                self.get_logger().debug(f'frame left unfinished at shutdown: {error}')
                return
            outcome = FAILED
            self.status.failures += 1
            self.status.last_error = f'{type(error).__name__}: {error}'
            self.get_logger().error(f'frame skipped: {self.last_error}',
                                    throttle_duration_sec=5.0)
            self.get_logger().debug(traceback.format_exc())
        finally:
            self.status.latencies_ms.append(1e3 * (time.perf_counter() - start))
        self.report_outcome(views, outcome)

    def process(self, views: Views) -> None:
        """Handle one synchronised two-view frame (``{camera: {key: msg}}``)."""
        raise NotImplementedError

    def record_stats(self, stats: dict[str, float]) -> None:
        """Figures of the last frame shown on /diagnostics (stage times, counts, fitness)."""
        self.status.stats = dict(stats)

    def _clock_values(self) -> dict[str, str | int]:
        """/diagnostics keys on the input stamps' clock (:meth:`StageStatus.clock_values`)."""
        return self.status.clock_values(self._inputs.jumps if self._inputs else None)

    def diagnostics_report(self) -> tuple[Any, str, dict[str, Any]]:
        """(level, message, values) that /diagnostics shows for this node now."""
        return self.status.report(
            inputs=self._inputs, rate_dropped=self.rate_cap.dropped,
            entrance_dropped=self.entrance_dropped, parameters=self.parameters)

    def _publish_diagnostics(self) -> None:
        level, message, values = self.diagnostics_report()
        self._diagnostics.publish(diagnostic_array(
            self.get_clock().now().to_msg(), self.get_name(), level, message, values))
