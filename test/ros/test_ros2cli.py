"""The real ros2 command line sees this run's message packages (the ament index)."""
import pytest
from ros2_tools import needs_ros2, run_ros2

pytestmark = [pytest.mark.ros, needs_ros2]


def test_ros2_knows_the_message_packages_the_graph_uses():
    result = run_ros2(['interface', 'show', 'diagnostic_msgs/msg/DiagnosticArray'], check=True)
    assert 'DiagnosticStatus[] status' in result.stdout
