"""The localiser's observed rig on the wire: geometry_msgs/PoseArray <-> camera poses."""
import numpy as np
import pytest

from tlessbot_ros.conversions import RclpyFactory, RosbagsFactory
from tlessbot_ros.conversions.pose import (
    camera_poses_to_pose_array,
    pose_array_to_camera_poses,
)
from tlessbot_ros.core.common import default_rig

FACTORIES = [pytest.param(RosbagsFactory(), id='rosbags'),
             pytest.param(RclpyFactory(), id='rclpy', marks=pytest.mark.ros)]
NAMES = ('top', 'side')


@pytest.mark.parametrize('factory', FACTORIES)
def test_camera_poses_round_trip_in_the_order_of_the_names(factory):
    rig = default_rig()
    poses = {name: rig[name].T_world_camera for name in NAMES}
    msg = camera_poses_to_pose_array(poses, names=NAMES, frame_id='world', stamp_ns=7,
                                     factory=factory)
    assert msg.header.frame_id == 'world' and len(msg.poses) == 2
    assert msg.poses[0].position.z == pytest.approx(1.1)      # top first
    back = pose_array_to_camera_poses(msg, names=NAMES)
    for name in NAMES:
        np.testing.assert_allclose(back[name], poses[name], atol=1e-12)
    with pytest.raises(ValueError, match='expected 3 camera poses'):
        pose_array_to_camera_poses(msg, names=('top', 'side', 'third'))
    msg.poses[1].orientation.w = float('nan')
    with pytest.raises(ValueError, match='side'):
        pose_array_to_camera_poses(msg, names=NAMES)
