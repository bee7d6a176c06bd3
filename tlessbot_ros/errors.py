"""The project's exception hierarchy. Tools print ``str(error)`` on one line and exit non-zero."""


class TlessbotError(Exception):
    """Base class of every error this package raises on purpose."""


class ModelFileError(TlessbotError):
    """A classifier, template or CAD model file is missing, corrupt or of the wrong format."""


class BagError(TlessbotError):
    """A rosbag2 file is missing, corrupt, truncated or lacks a requested topic."""


class CalibrationError(TlessbotError):
    """Camera intrinsics or extrinsics are missing or inconsistent."""


class DatasetError(TlessbotError):
    """A dataset folder does not follow the expected (BOP) layout."""


class DeviceError(TlessbotError):
    """A camera is missing, busy or stopped delivering frames."""


class PartNameError(TlessbotError):
    """A part's name (its CAD file's stem) cannot name a ROS topic or frame."""
