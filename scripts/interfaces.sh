#!/usr/bin/env bash
# Build the message packages the PyPI wheels lack (tf2_msgs, vision_msgs, tlessbot_interfaces,
# from interfaces/) with CMake and install them into the venv, where every process of it finds
# them: Python modules in its site-packages, libraries in its lib/ (on LD_LIBRARY_PATH through
# the wheels' bootstrapper). Stand-alone set-up only: a ROS install has tf2_msgs and vision_msgs
# from apt and builds tlessbot_interfaces with colcon (docs/design.md, "Interfaces").
# Idempotent: a second run with unchanged sources takes well under a second.
#   usage: scripts/interfaces.sh [VENV]      (default .venv)
set -euo pipefail
cd "$(dirname "$0")/.."

VENV=${1:-${VENV:-.venv}}
PACKAGES=(tf2_msgs vision_msgs tlessbot_interfaces)   # dependencies first
BUILD=${TLESSBOT_INTERFACES_BUILD:-build/interfaces}

stamp_file="$VENV/.tlessbot-interfaces-stamp"
stamp=$( { find interfaces -type f | LC_ALL=C sort | xargs cat; cat scripts/interfaces.sh \
           requirements/interfaces-build.txt; } | sha256sum | cut -d' ' -f1)
if [ -f "$stamp_file" ] && [ "$(cat "$stamp_file")" = "$stamp" ]; then
    echo "setup: interfaces are up to date"
    exit 0
fi

# CMake, a C/C++ compiler and Python's headers: installed once, as root, when missing.
py_include=$("$VENV/bin/python" -c 'import sysconfig; print(sysconfig.get_paths()["include"])')
missing=()
command -v cmake >/dev/null || missing+=(cmake)
command -v g++ >/dev/null || missing+=(g++)
command -v make >/dev/null || command -v ninja >/dev/null || missing+=(make)
[ -f "$py_include/Python.h" ] || missing+=(python3-dev)
if [ ${#missing[@]} -gt 0 ]; then
    if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; then
        echo "setup: installing ${missing[*]} (to build the message packages, once)"
        (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq \
            "${missing[@]}") >/dev/null
    else
        echo "setup: ${missing[*]} missing; run:  sudo apt-get install -y ${missing[*]}" >&2
        exit 1
    fi
fi

# 1. The build-time wheels, by name: the message wheels do not depend on them.
"$VENV/bin/python" -m pip install -q -c constraints.txt -r requirements/interfaces-build.txt \
    2>&1 | { grep -v "^WARNING: Location 'file://" || true; }

# 2. The message wheels' exported CMake files name the Python and numpy include folders of the
# machine they were built on; point them at this venv's.
np_include=$("$VENV/bin/python" -c 'import numpy, os; print(os.path.realpath(numpy.get_include()))')
{ grep -l '/opt/python/cp3' "$VENV"/share/*/cmake/*Export.cmake 2>/dev/null || true; } | while read -r f; do
    sed -i -e "s#/opt/python/cp3[0-9]*-cp3[0-9]*/lib/python3\.[0-9]*/site-packages/numpy/_\{0,1\}core/include#$np_include#g" \
           -e "s#/opt/python/cp3[0-9]*-cp3[0-9]*/include/python3\.[0-9]*#$py_include#g" "$f"
done

# 3. Configure, build and install each package into the venv.
prefix=$(cd "$VENV" && pwd)
generator=()
command -v ninja >/dev/null && generator=(-G Ninja)
export AMENT_PREFIX_PATH="$prefix" CMAKE_PREFIX_PATH="$prefix" PATH="$prefix/bin:$PATH"
start=$(date +%s%N)
for package in "${PACKAGES[@]}"; do
    log="$BUILD/$package.log"
    mkdir -p "$BUILD"
    if ! { cmake -S "interfaces/$package" -B "$BUILD/$package" "${generator[@]}" \
             -DCMAKE_BUILD_TYPE=Release -DBUILD_TESTING=OFF -DCMAKE_INSTALL_PREFIX="$prefix" \
             -DPython3_EXECUTABLE="$prefix/bin/python" -DPYTHON_EXECUTABLE="$prefix/bin/python" \
           && cmake --build "$BUILD/$package" -j "$(nproc)" \
           && cmake --install "$BUILD/$package"; } >"$log" 2>&1; then
        tail -n 30 "$log" >&2
        echo "setup: building the message package $package failed (log: $log)" >&2
        exit 1
    fi
done
ms=$(( ($(date +%s%N) - start) / 1000000 ))
echo "setup: message packages ${PACKAGES[*]} built in $((ms / 1000)).$(( ms % 1000 / 100 )) s"
echo "$stamp" > "$stamp_file"
