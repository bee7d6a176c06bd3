"""Pose fits in worker processes, so the parts of one frame are fitted at the same time on
several cores (``PoseWorkerPool``). No ROS here: the pose node and the tools use it."""
