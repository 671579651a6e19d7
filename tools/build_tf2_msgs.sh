#!/usr/bin/env bash
# Build tf2_msgs (tools/tf2_msgs: TFMessage, the type of /tf and /tf_static) into a
# virtual environment when it cannot import it: PyPI has ROS 2 Jazzy's message
# wheels and its message toolchain but no tf2_msgs. Usage (from the repository root;
# `make install` runs it):
#
#     tools/build_tf2_msgs.sh .venv
#
# Installs the toolchain (requirements/ros-jazzy-interfaces.txt), then cmake
# configures, builds and installs the package into the venv's prefix (C/C++ libraries
# in lib/, the Python package in site-packages, the ament index in share/). Nothing to
# do, at once, when tf2_msgs is importable (built before, or a ROS 2 install's).
# A failed build is one line on stderr and exit 0 (the stack runs without /tf), except
# under CI (CI set), where it is an error. The build's output: <venv>/build/tf2_msgs.log.
set -uo pipefail

venv="${1:?usage: tools/build_tf2_msgs.sh VENV}"
root="$(cd "$(dirname "$0")/.." && pwd)"
prefix="$(cd "$venv" && pwd)"
python="$prefix/bin/python"
build="$prefix/build/tf2_msgs"
log="$prefix/build/tf2_msgs.log"

if "$python" -c 'import tf2_msgs.msg' 2>/dev/null; then
    exit 0
fi

build_it() {
    set -e
    echo "== toolchain"
    "$python" -m pip install --quiet -c "$root/requirements/constraints.txt" \
        -r "$root/requirements/ros-jazzy-interfaces.txt"
    echo "== configure"
    rm -rf "$build"
    cmake -S "$root/tools/tf2_msgs" -B "$build" -DCMAKE_BUILD_TYPE=Release \
        -DCMAKE_INSTALL_PREFIX="$prefix" -DCMAKE_PREFIX_PATH="$prefix" \
        -DPython3_EXECUTABLE="$python" -DBUILD_TESTING=OFF
    echo "== build"
    cmake --build "$build" --parallel "$(nproc 2>/dev/null || echo 2)"
    echo "== install"
    cmake --install "$build"
    "$python" -c 'from tf2_msgs.msg import TFMessage; TFMessage()'
}

mkdir -p "$prefix/build"
echo "building tf2_msgs into $venv (log: $venv/build/tf2_msgs.log)"
(build_it) >"$log" 2>&1      # not in an `if`: there, set -e would not apply
if [ $? -eq 0 ]; then
    exit 0
fi
echo "tf2_msgs could not be built (it needs cmake and a C/C++ compiler; see" \
     "$venv/build/tf2_msgs.log): the stack runs without /tf and /tf_static;" \
     "\`make tf2-msgs\` tries again" >&2
if [ -n "${CI:-}" ]; then
    exit 1
fi
exit 0
