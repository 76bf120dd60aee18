# Sourced by the scripts that launch nodes: ROOT (the package), WS (the catkin
# workspace: $DSS_WS, default .ws) sourced, Debian's ROS first on PATH, and
# ROS_HOME (logs) inside the workspace unless set.
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
WS="${DSS_WS:-$ROOT/.ws}"
export PATH="/usr/bin:$PATH"
set +u  # ROS's setup scripts read unset variables
# shellcheck disable=SC1091
source "$WS/devel/setup.bash"
set -u
export ROS_HOME="${ROS_HOME:-$WS/ros_home}"
