"""Pure algorithms on numpy / OpenCV / scikit-image / scikit-learn / Open3D. Never imports ROS."""
