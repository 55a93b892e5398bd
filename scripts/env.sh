# Sourced by the scripts: the ROS environment of this workspace.
# (Setup scripts of some distributions read unset variables: no `set -u` here.)
ECAR_ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
if [[ -f /opt/ros/noetic/setup.bash ]]; then
  # shellcheck disable=SC1091
  source /opt/ros/noetic/setup.bash
fi
if [[ -f "$ECAR_ROOT/devel/setup.bash" ]]; then
  # shellcheck disable=SC1091
  source "$ECAR_ROOT/devel/setup.bash"
fi
# The system Python has the ROS modules (a pyenv python3 may come first on PATH).
export PATH="/usr/bin:$PATH"
export ROS_PYTHON_VERSION=3
export ROS_LOG_DIR="${ROS_LOG_DIR:-$ECAR_ROOT/logs/ros}"
