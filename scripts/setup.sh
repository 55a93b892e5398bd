#!/usr/bin/env bash
# Installs every dependency of eCAR from distribution packages (no downloads
# other than the package manager's) and builds the catkin workspace.
#
# Debian 12: ROS 1 comes from Debian's own packages (catkin, roscpp, ...).
# Ubuntu 20.04: ROS Noetic from /opt/ros/noetic (ros-noetic-* packages).
#
# Usage: scripts/setup.sh [--no-build]
# Re-running it when nothing changed is fast: apt is skipped when every
# package is present and catkin_make only rebuilds what changed.
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
BUILD=1
[[ "${1:-}" == "--no-build" ]] && BUILD=0

SUDO=""
if [[ $(id -u) -ne 0 ]]; then SUDO="sudo"; fi

COMMON_PKGS=(
  build-essential cmake pkg-config
  libopencv-dev libeigen3-dev libceres-dev libsqlite3-dev sqlite3 zlib1g-dev libyaml-cpp-dev nlohmann-json3-dev
  libgtest-dev googletest
  python3-numpy python3-matplotlib python3-yaml
  libturbojpeg0-dev  # JPEG headers checked before decoding (ecar_core/io/jpeg.h)
  clang libclang-rt-14-dev  # the sanitizer and fuzz build (scripts/test.sh --sanitize, scripts/fuzz.sh)
  lld  # links in a fifth of GNU ld's time (about 200 executables and libraries, with the tests)
  xvfb imagemagick clang-format
  iproute2 procps  # ip netns, tc, sysctl: the shared link (ecar_sim.links, run_session --link)
)

if [[ -d /opt/ros/noetic ]]; then
  ROS_SETUP=/opt/ros/noetic/setup.bash
  ROS_PKGS=(
    ros-noetic-catkin ros-noetic-roscpp ros-noetic-rosbag ros-noetic-roslaunch ros-noetic-rostest
    ros-noetic-tf2-ros ros-noetic-tf2-eigen ros-noetic-image-transport ros-noetic-cv-bridge
    ros-noetic-nodelet ros-noetic-pluginlib ros-noetic-dynamic-reconfigure
    ros-noetic-interactive-markers ros-noetic-rviz ros-noetic-visualization-msgs
    ros-noetic-sensor-msgs ros-noetic-geometry-msgs ros-noetic-nav-msgs ros-noetic-std-srvs
    ros-noetic-message-generation ros-noetic-message-runtime ros-noetic-rostopic ros-noetic-rosnode
  )
else
  ROS_SETUP=""
  ROS_PKGS=(
    catkin python3-catkin-pkg python3-rospkg python3-empy
    libroscpp-dev librosbag-dev python3-rosbag python3-roslaunch python3-rostest python3-rosunit
    librostest-dev
    python3-rospy python3-rostopic python3-rosnode python3-rosservice python3-rosparam python3-rosmsg
    rosbash rosout ros-core-dev
    libtf2-ros-dev libtf2-eigen-dev python3-tf2-ros libimage-transport-dev libcv-bridge-dev python3-cv-bridge
    libnodelet-dev libnodeletlib-dev libnodeletlib-tools pluginlib-dev
    libdynamic-reconfigure-config-init-mutex-dev python3-dynamic-reconfigure
    libinteractive-markers-dev rviz librviz-dev
    libvisualization-msgs-dev python3-visualization-msgs libsensor-msgs-dev libgeometry-msgs-dev libnav-msgs-dev libstd-srvs-dev
    ros-message-generation ros-message-runtime python3-genmsg python3-gencpp python3-genpy
  )
fi

ALL_PKGS=("${COMMON_PKGS[@]}" "${ROS_PKGS[@]}")
missing=()
for p in "${ALL_PKGS[@]}"; do
  if ! dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed"; then
    missing+=("$p")
  fi
done
if ((${#missing[@]})); then
  echo "[setup] installing ${#missing[@]} missing packages: ${missing[*]}"
  export DEBIAN_FRONTEND=noninteractive
  $SUDO apt-get update -qq
  $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}"
else
  echo "[setup] all ${#ALL_PKGS[@]} packages present"
fi

if ((BUILD)); then
  # Some distributions' setup scripts read unset variables.
  set +u
  [[ -n "$ROS_SETUP" ]] && source "$ROS_SETUP"
  set -u
  cd "$ROOT"
  echo "[setup] building the workspace in $ROOT/build"
  # The system Python: a pyenv/venv python3 first on PATH lacks catkin_pkg.
  # LLVM's linker: a fresh build's and its tests' links take 10 s instead of 45 on 2 cores.
  linker=()
  if command -v ld.lld >/dev/null; then
    linker=(-DCMAKE_EXE_LINKER_FLAGS=-fuse-ld=lld -DCMAKE_SHARED_LINKER_FLAGS=-fuse-ld=lld
            -DCMAKE_MODULE_LINKER_FLAGS=-fuse-ld=lld)
  fi
  catkin_make -DPYTHON_EXECUTABLE=/usr/bin/python3 -DPython3_EXECUTABLE=/usr/bin/python3 \
    -DCMAKE_BUILD_TYPE=Release "${linker[@]}" \
    -j"$(nproc)" >"$ROOT/build.log" 2>&1 || { tail -60 "$ROOT/build.log"; echo "[setup] build failed (full log: build.log)"; exit 1; }
  grep -E "warning:" "$ROOT/build.log" | sort -u | head -20 || true
  echo "[setup] build ok"
fi
