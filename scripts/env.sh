# Source this file (bash) to use the project from a shell:
#   source scripts/env.sh
# It sources the catkin workspace (whose env hook puts .venv/bin first on PATH)
# so that rosrun, roslaunch, rostest, uav-sitl, uav-mavlink-router and the
# project's Python all work together.
_uav_repo="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
if [ ! -f "$_uav_repo/catkin_ws/devel/setup.bash" ]; then
  echo "catkin_ws/devel/setup.bash is missing: run 'make setup' first" >&2
  return 1 2>/dev/null || exit 1
fi
# shellcheck disable=SC1091
source "$_uav_repo/catkin_ws/devel/setup.bash"
unset _uav_repo
