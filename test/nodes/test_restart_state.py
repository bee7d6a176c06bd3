"""What a restarted node can receive: nothing from before it was there.

A node started again subscribes anew. Its subscriptions are VOLATILE, so DDS hands it only
samples written after it matched, never the history (RESULT_QOS keeps 10) the upstream
publisher still holds for its old readers; and launch's readiness monitor takes the new
process's readiness only from that process, not from a status the dead one sent.
"""
import subprocess
import sys
import time

import pytest

pytestmark = pytest.mark.ros

# An upstream stage that lives on: 20 results (more than the history of 10 it keeps) before the
# subscriber comes, then, once its writer has matched the subscriber, more at 20 Hz.
PUBLISHER = """
import time
import rclpy
from sensor_msgs.msg import Image
from tlessbot_ros.nodes.common import RESULT_QOS
rclpy.init()
node = rclpy.create_node('upstream')
publisher = node.create_publisher(Image, 'restart_test/classes', RESULT_QOS)
message = Image(encoding='16UC1')
message.header.frame_id = 'before'
for _ in range(20):
    publisher.publish(message)
print('sent', flush=True)
while publisher.get_subscription_count() == 0:
    time.sleep(0.05)
message.header.frame_id = 'after'
while True:
    publisher.publish(message)
    time.sleep(0.05)
"""


@pytest.mark.parametrize('input_qos', ['reliable', 'sensor_data'])
def test_a_new_subscriber_gets_no_sample_written_before_it_came(input_qos):
    import rclpy
    from sensor_msgs.msg import Image

    from tlessbot_ros.nodes.stage import input_profile

    upstream = subprocess.Popen([sys.executable, '-c', PUBLISHER], stdout=subprocess.PIPE,
                                text=True)
    rclpy.init()
    try:
        assert upstream.stdout.readline() == 'sent\n'
        node = rclpy.create_node('restarted_stage')
        received = []
        node.create_subscription(Image, 'restart_test/classes',
                                 lambda msg: received.append(msg.header.frame_id),
                                 input_profile(input_qos, 10))
        deadline = time.monotonic() + 30
        while received.count('after') < 5 and time.monotonic() < deadline:
            rclpy.spin_once(node, timeout_sec=0.1)
        assert received.count('after') >= 5
        assert 'before' not in received
        node.destroy_node()
    finally:
        upstream.kill()
        upstream.wait()
        rclpy.try_shutdown()


def test_readiness_of_a_restarted_node_comes_from_its_new_process():
    import rclpy

    from tlessbot_ros.nodes.common import RESULT_QOS, message_class
    from tlessbot_ros.nodes.diagnostics import OK, diagnostic_array
    from tlessbot_ros.tools.support.readiness import ReadinessMonitor

    rclpy.init()
    try:
        monitor = ReadinessMonitor(['localiser', 'classifier'])
        node = rclpy.create_node('stage_statuses')
        publisher = node.create_publisher(
            message_class('diagnostic_msgs/msg/DiagnosticArray'), '/diagnostics', RESULT_QOS)

        def send_until(condition, statuses) -> bool:
            """Publish ``statuses`` (name, pid, ready) in one array until ``condition``."""
            deadline = time.monotonic() + 30
            while time.monotonic() < deadline:
                array = diagnostic_array(node.get_clock().now().to_msg(), '', OK, '', {})
                array.status = [diagnostic_array(
                    array.header.stamp, name, OK, 'ok',
                    {'ready': ready, 'ready_after_s': '1.0', 'pid': pid}).status[0]
                    for name, pid, ready in statuses]
                publisher.publish(array)
                monitor.poll(0.1)
                if condition():
                    return True
            return False

        assert send_until(lambda: monitor.all_ready,
                          [('localiser', '100', 'true'), ('classifier', '7', 'true')])
        monitor.restarted('localiser', 200)
        monitor.restarted('classifier', 8)
        assert not monitor.is_ready('localiser') and not monitor.all_ready
        # the dead process's status arrives late, next to a status that shows it was handled
        assert send_until(lambda: monitor.is_ready('classifier'),
                          [('localiser', '100', 'true'), ('classifier', '8', 'true')])
        assert not monitor.is_ready('localiser')
        assert send_until(lambda: monitor.is_ready('localiser'),
                          [('localiser', '200', 'true')])
        node.destroy_node()
        monitor.close()
    finally:
        rclpy.try_shutdown()
