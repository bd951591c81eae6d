# Source me: the environment every by_your_command process runs in (venv + colcon install).
# DDS stays on this machine unless the caller already chose otherwise (DESIGN.md §11).
_byc_root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
export VIRTUAL_ENV="$_byc_root/.venv"
export PATH="$VIRTUAL_ENV/bin:$PATH"
export AMENT_PREFIX_PATH="$VIRTUAL_ENV${AMENT_PREFIX_PATH:+:$AMENT_PREFIX_PATH}"
if [ -f "$_byc_root/install/setup.bash" ]; then
  # colcon's scripts read unset variables: relax `set -u` while sourcing them.
  case $- in *u*) _byc_nounset=1; set +u ;; *) _byc_nounset= ;; esac
  # shellcheck disable=SC1091
  . "$_byc_root/install/setup.bash"
  [ -n "$_byc_nounset" ] && set -u
  unset _byc_nounset
  # Our executables (what `ros2 run by_your_command X` would start) by name.
  export PATH="$_byc_root/install/by_your_command/lib/by_your_command:$PATH"
fi
export ROS_AUTOMATIC_DISCOVERY_RANGE="${ROS_AUTOMATIC_DISCOVERY_RANGE:-LOCALHOST}"
export RMW_IMPLEMENTATION="${RMW_IMPLEMENTATION:-rmw_fastrtps_cpp}"
export PYTHONDONTWRITEBYTECODE=1
unset _byc_root
