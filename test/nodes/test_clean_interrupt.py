"""Ctrl-C ends every node cleanly while it works: exit code 0, no traceback, no error line, no
"Failed to publish log message to rosout" (real processes; Ctrl-C is SIGINT to the process
group, as a terminal sends it, so launch's nodes get it twice: from the terminal and from
launch)."""
import sys

import pytest
from running import Running, unclean_lines

from tlessbot_ros.tools.support.defaults import DEFAULT_BAG

pytestmark = [pytest.mark.ros]

CLI = [sys.executable, '-m', 'tlessbot_ros.tools.cli']

# camera_driver with a stand-in for the RealSense: frames of a flat table at 30 fps.
_FAKE_CAMERA_DRIVER = """
import sys
import time
import numpy as np
from tlessbot_ros.core.common import d415_intrinsics
from tlessbot_ros.nodes import camera_driver
from tlessbot_ros.sensors.realsense import RealSenseFrame

class FakeCamera:
    def __init__(self, params):
        self.params, self.is_open = params, False

    def open(self):
        self.is_open = True

    def read(self):
        time.sleep(1.0 / self.params.fps)
        w, h = self.params.width, self.params.height
        return RealSenseFrame(np.full((h, w, 3), 90, np.uint8), np.full((h, w), 800, np.uint16),
                              d415_intrinsics(w, h))

    def close(self):
        self.is_open = False

camera_driver.RealSenseCamera = FakeCamera
camera_driver.main(sys.argv[1:])
"""


def test_camera_driver_stops_cleanly_while_streaming():
    driver = Running([sys.executable, '-c', _FAKE_CAMERA_DRIVER, '--ros-args', '-r',
                      '__ns:=/side', '-p', 'camera_name:=side'])
    # a subscriber of the cloud: the driver then builds one per frame (busiest when stopped)
    echo = Running([*CLI, 'echo', '/side/depth/color/points', '--timeout', '120'])
    try:
        assert driver.wait_for('streaming 640x480 @ 30 fps', 120), driver.output
        assert echo.wait_for("frame_id: 'side_color_optical_frame'", 120, count=5), echo.output
        code = driver.interrupt()
        assert echo.interrupt() == 0, echo.output
    finally:
        driver.kill()
        echo.kill()
    assert code == 0, driver.output
    assert not unclean_lines(driver.output), driver.output


@pytest.mark.rosbag
@pytest.mark.slow
def test_the_graph_stops_cleanly_while_it_processes_a_looped_bag():
    """launch with the three perception nodes (the pose estimator with its worker process, as
    config/cell.yaml has it) and the demo bag in a loop: Ctrl-C once frames flow through."""
    launch = Running([*CLI, 'launch', '--replay', str(DEFAULT_BAG), '--loop',
                      '--nodes', 'localiser', 'classifier', 'pose_estimator'])
    probe = None
    try:
        assert launch.wait_for('[launch] graph ready', 600), launch.output
        probe = Running([*CLI, 'echo', '/classifier/side/classes', '--count', '3',
                         '--timeout', '120'])
        assert probe.wait(240) == 0, probe.output + launch.output
        code = launch.interrupt(120)
    finally:
        launch.kill()
        if probe is not None:
            probe.kill()
    assert code == 0, launch.output
    assert not unclean_lines(launch.output), launch.output
    for node in ('localiser', 'classifier', 'pose_estimator', 'replay'):
        assert f'[{node}]' in launch.output, launch.output   # each one's lines were seen


def test_a_signal_whose_interrupt_was_swallowed_still_stops_the_loop():
    """The handler's KeyboardInterrupt can land inside a finaliser, which swallows it; the spin
    loops' raise_if_interrupted() then still stops the tool."""
    import signal

    from tlessbot_ros.nodes import common

    saved = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        common.raise_if_interrupted()                 # nothing received: no interrupt
        assert common.interrupt_on_signals()
        try:
            signal.raise_signal(signal.SIGTERM)
        except KeyboardInterrupt:
            pass                                      # as if a finaliser had swallowed it
        with pytest.raises(KeyboardInterrupt):
            common.raise_if_interrupted()
    finally:
        common._SIGNALS_RECEIVED.clear()
        for signum, handler in saved.items():
            signal.signal(signum, handler)


def test_a_half_built_rclpy_task_after_a_signal_prints_no_traceback(capsys, monkeypatch):
    # A signal's KeyboardInterrupt landing in rclpy's Task.__init__ leaves a Task without its
    # fields, whose finaliser then fails; after a signal that error is dropped, before one it
    # is reported as Python reports any error in a finaliser.
    import gc
    import sys

    from rclpy.task import Task

    from tlessbot_ros.nodes import common

    monkeypatch.setattr(sys, 'unraisablehook', common.quiet_half_built_futures)
    monkeypatch.setattr(common, '_SIGNALS_RECEIVED', [15])
    task = Task.__new__(Task)
    del task
    gc.collect()
    assert 'Traceback' not in capsys.readouterr().err
    reported = []
    monkeypatch.setattr(common, '_DEFAULT_UNRAISABLEHOOK', reported.append)
    monkeypatch.setattr(common, '_SIGNALS_RECEIVED', [])
    task = Task.__new__(Task)
    del task
    gc.collect()
    assert len(reported) == 1 and isinstance(reported[0].exc_value, AttributeError)


def test_a_signal_landing_in_an_rclpy_finaliser_prints_no_traceback(monkeypatch):
    # The handler's KeyboardInterrupt raised inside rclpy's Future.__del__ is printed by Python
    # as ignored; after a signal it is dropped (the spin loop raises it after the turn), before
    # one it is reported.
    import gc
    import sys

    from rclpy.task import Future

    from tlessbot_ros.nodes import common

    def interrupted(self):
        raise KeyboardInterrupt

    interrupted.__qualname__, interrupted.__module__ = 'Future.__del__', 'rclpy.task'
    monkeypatch.setattr(Future, '__del__', interrupted)
    monkeypatch.setattr(sys, 'unraisablehook', common.quiet_half_built_futures)
    reported = []
    monkeypatch.setattr(common, '_DEFAULT_UNRAISABLEHOOK', reported.append)
    for received in ([2], []):
        monkeypatch.setattr(common, '_SIGNALS_RECEIVED', received)
        future = Future()
        del future
        gc.collect()
        assert len(reported) == (0 if received else 1)
    assert isinstance(reported[0].exc_value, KeyboardInterrupt)


def test_an_error_from_a_turn_cut_by_a_signal_is_the_interrupt(monkeypatch):
    """A KeyboardInterrupt that lands inside pybind11 (rclpy converting a message it takes)
    comes out as a RuntimeError; after a signal it is the interrupt, before one it is not."""
    import pytest

    from tlessbot_ros.nodes import common

    def cut_turn():
        raise RuntimeError("Unable to convert call argument '0' to Python object")

    monkeypatch.setattr(common, '_SIGNALS_RECEIVED', [])
    with pytest.raises(RuntimeError):
        common.spin_once_or_interrupt(cut_turn)
    common.spin_once_or_interrupt(lambda: None)   # a quiet turn, no signal: nothing raised
    monkeypatch.setattr(common, '_SIGNALS_RECEIVED', [2])
    with pytest.raises(KeyboardInterrupt):
        common.spin_once_or_interrupt(cut_turn)
    with pytest.raises(KeyboardInterrupt):
        common.spin_once_or_interrupt(lambda: None)
