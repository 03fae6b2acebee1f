# Sourced by the scripts: the environment the ROS 2 PyPI wheels need.
export RMW_IMPLEMENTATION="${RMW_IMPLEMENTATION:-rmw_fastrtps_cpp}"
export PATH="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)/.venv/bin:$PATH"
# Matplotlib must never try to open a window on a headless machine.
export MPLBACKEND="${MPLBACKEND:-Agg}"
