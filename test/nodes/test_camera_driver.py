"""camera_driver without a device: it reports ERROR on /diagnostics and keeps running."""
import time

import pytest

pytestmark = pytest.mark.ros


def test_no_device_reports_error_and_stays_alive(monkeypatch):
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
    from rclpy.parameter import Parameter

    from tlessbot_ros.nodes import camera_driver
    from tlessbot_ros.sensors import realsense

    monkeypatch.setattr(realsense, 'connected_serials', lambda: [])
    rclpy.init()
    try:
        node = camera_driver.CameraDriverNode(parameter_overrides=[
            Parameter('camera_name', value='side'), Parameter('reconnect_period_s', value=0.2)])
        listener = rclpy.create_node('diag_listener')
        received = []
        listener.create_subscription(DiagnosticArray, '/diagnostics',
                                     lambda msg: received.append(msg), 10)
        executor = rclpy.executors.SingleThreadedExecutor()
        executor.add_node(node)
        executor.add_node(listener)
        deadline = time.monotonic() + 15
        while len(received) < 2 and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.1)
        assert len(received) >= 2
        status = received[-1].status[0]
        assert status.level == DiagnosticStatus.ERROR
        assert 'no RealSense device connected' in status.message
        assert node._thread.is_alive()  # still retrying
        assert node.params.camera_name == 'side'
        node.destroy_node()
        listener.destroy_node()
    finally:
        rclpy.try_shutdown()
