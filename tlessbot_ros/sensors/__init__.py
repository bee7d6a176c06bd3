"""Camera access: pyrealsense2 (imported lazily) and a device-free frame path."""
