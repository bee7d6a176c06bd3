"""Default inputs of the commands."""
from __future__ import annotations

from tlessbot_ros.io.config import package_path

DEFAULT_BAG = package_path('bags', 'demo')   # the demo bag: two-view frames with ground truth
