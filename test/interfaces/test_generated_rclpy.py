"""The generated packages work from rclpy in a fresh process with no exported paths:
a Detection3DArray and a TFMessage go through DDS with Jazzy's type hashes, GetObjects answers."""
import os
import subprocess
import sys

import pytest

pytestmark = pytest.mark.ros

SCRIPT = r"""
import time
import rclpy
from rclpy.executors import SingleThreadedExecutor
from tf2_msgs.msg import TFMessage
from tlessbot_interfaces.srv import GetObjects
from vision_msgs.msg import Detection3DArray

rclpy.init()
node = rclpy.create_node('generated_check')
got = []
node.create_subscription(Detection3DArray, '/check/detections', got.append, 10)
pub = node.create_publisher(Detection3DArray, '/check/detections', 10)
tf = node.create_publisher(TFMessage, '/check/tf', 10)
node.create_service(GetObjects, '/check/get_objects',
                    lambda req, res: setattr(res, 'message', ','.join(req.parts)) or res)
client = node.create_client(GetObjects, '/check/get_objects')
executor = SingleThreadedExecutor()
executor.add_node(node)
assert client.wait_for_service(timeout_sec=10)
future = client.call_async(GetObjects.Request(parts=['obj_05', 'obj_07']))
deadline = time.monotonic() + 20
while (not got or not future.done()) and time.monotonic() < deadline:
    msg = Detection3DArray()
    msg.header.frame_id = 'world'
    pub.publish(msg)
    executor.spin_once(timeout_sec=0.1)
print('received', len(got) > 0, got[0].header.frame_id if got else None)
print('answer', future.result().message if future.done() else None)
for topic in ('/check/detections', '/check/tf'):
    info = node.get_publishers_info_by_topic(topic)[0]
    print('hash', info.topic_type, str(info.topic_type_hash))
"""


def test_generated_packages_from_rclpy():
    env = {k: v for k, v in os.environ.items()
           if k not in ('PYTHONPATH', 'AMENT_PREFIX_PATH', 'LD_LIBRARY_PATH',
                        '_ROS_WHEELS_BOOTSTRAP_COMPLETE')}
    done = subprocess.run([sys.executable, '-c', SCRIPT], env=env, capture_output=True,
                          text=True, timeout=120, cwd='/')
    out = done.stdout
    assert done.returncode == 0, out + done.stderr
    assert 'received True world' in out
    assert 'answer obj_05,obj_07' in out
    assert ('hash vision_msgs/msg/Detection3DArray RIHS01_793f5eab9595ac1c0da07873cc859db42eae51f0'
            'ee76056db8562515d830e018') in out
    assert ('hash tf2_msgs/msg/TFMessage RIHS01_e369d0f05a23ae52508854b66f6aa0437f3449d652e8cbf2'
            '2d5abe85d020f087') in out
