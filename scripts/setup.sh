#!/usr/bin/env bash
# Idempotent stand-alone set-up: system library check, .venv, pinned Python dependencies, the
# package itself (editable), the message packages PyPI lacks (scripts/interfaces.sh). A second
# run with unchanged requirements takes a second or two.
set -euo pipefail
cd "$(dirname "$0")/.."

PYTHON=${PYTHON:-python3}
VENV=${VENV:-.venv}

"$PYTHON" - <<'PY' || { echo "setup: Python 3.10-3.12 is required (PYTHON=$PYTHON)" >&2; exit 1; }
import sys
sys.exit(0 if (3, 10) <= sys.version_info[:2] <= (3, 12) else 1)
PY

# Open3D's wheel links against libusb-1.0 (librealsense inside it); Debian/Ubuntu ship it apart.
if ! ldconfig -p 2>/dev/null | grep -q 'libusb-1.0.so.0'; then
    if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; then
        echo "setup: installing libusb-1.0-0 (needed by open3d and pyrealsense2)"
        (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq libusb-1.0-0) \
            >/dev/null
    else
        echo "setup: libusb-1.0 is missing; run:  sudo apt-get install -y libusb-1.0-0" >&2
        exit 1
    fi
fi

[ -x "$VENV/bin/python" ] || "$PYTHON" -m venv "$VENV"

# The real jazzy ros2 command line and ros2 launch (ros2cli, launch, launch_ros: not on PyPI),
# for the tests that drive the graph with them. CI has them beside the clone in ../shared; a
# ROS 2 install has its own, and a clone without them skips those tests. Idempotent (~1 s).
install_ros2_cli() {
    local source=${TLESSBOT_ROS2_CLI:-../shared/ros2-cli}
    if [ -x "$source/install.sh" ]; then
        "$source/install.sh" "$VENV" | { grep -v "^WARNING: Location 'file://" || true; }
    else
        echo "setup: $source not found: the tests that use the ros2 command line are skipped"
    fi
}

# setup.cfg installs the executables into lib/tlessbot_ros, where `ros2 run` looks for them; the
# stand-alone venv also gets `tlessbot` in its bin/, so `source .venv/bin/activate` finds it.
link_cli() {
    [ -x "$VENV/lib/tlessbot_ros/tlessbot" ] && ln -sf ../lib/tlessbot_ros/tlessbot "$VENV/bin/tlessbot"
    return 0
}

stamp_file="$VENV/.tlessbot-setup-stamp"
stamp=$(cat constraints.txt requirements/*.txt setup.py setup.cfg package.xml scripts/setup.sh | sha256sum | cut -d' ' -f1)
if [ -f "$stamp_file" ] && [ "$(cat "$stamp_file")" = "$stamp" ]; then
    install_ros2_cli
    link_cli
    scripts/interfaces.sh "$VENV"
    echo "setup: $VENV is up to date"
    exit 0
fi

echo "setup: installing pinned dependencies into $VENV (first run takes a few minutes)"
# Some machines' pip configuration names local package folders that may not exist; pip then
# prints one warning per package. Filter those lines, keep everything else.
quiet_pip() {
    "$VENV/bin/python" -m pip "$@" 2>&1 | { grep -v "^WARNING: Location 'file://" || true; }
    return "${PIPESTATUS[0]}"
}
quiet_pip install -q -c constraints.txt \
    -r requirements/ros-pypi.txt -r requirements/dev.txt -e '.[realsense,foxglove]'
install_ros2_cli
link_cli
# tf2_msgs, vision_msgs and our GetObjects service: not on PyPI, built from interfaces/ with
# CMake into the venv (~10-60 s once; a second run checks a stamp).
scripts/interfaces.sh "$VENV"
# Compile the pose kernels and build the pose stage's start-up caches now, so that the first
# start of a node after set-up is as fast as the next (tlessbot warm-up; safe to repeat).
"$VENV/bin/python" -m tlessbot_ros.tools.cli warm-up \
    || echo "setup: warm-up failed; the nodes build their caches at their first start" >&2
echo "$stamp" > "$stamp_file"
echo "setup: done"
