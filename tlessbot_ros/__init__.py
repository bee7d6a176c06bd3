"""tlessbot_ros: two-view RGB-D perception for textureless T-LESS parts.

Layers (imports point down only):
    tools, nodes  ->  conversions, sensors, sim, io  ->  core
``tlessbot_ros.core`` and ``tlessbot_ros.conversions`` never import rclpy.
"""

__version__ = '0.1.0'
