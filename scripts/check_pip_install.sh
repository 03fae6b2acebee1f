#!/usr/bin/env bash
# Install this package as a user would, `pip install .` into a fresh virtual environment
# (the system's python and pip, nothing from .venv), then, from outside the source tree so
# that what runs is the installed package with only its declared dependencies: `sclam
# calibrate --urdf` on the demo recording, `sclam export` on its result and `sclam_node --help`.
# Pip's own settings (PIP_FIND_LINKS, pip.conf) apply as on any install.
# Usage: scripts/check_pip_install.sh [PYTHON]
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
python="${1:-python3}"
tmp="$(mktemp -d)"
trap 'rm -rf "$tmp"' EXIT
venv="$tmp/venv"

"$python" -m venv "$venv"
echo "[check] $("$venv/bin/python" --version), $("$venv/bin/python" -m pip --version | cut -d' ' -f1-2)"
echo "[check] pip install $root"
"$venv/bin/python" -m pip install --quiet "$root"

# The ROS 2 PyPI wheels need an RMW; matplotlib must not look for a display.
export RMW_IMPLEMENTATION="${RMW_IMPLEMENTATION:-rmw_fastrtps_cpp}" MPLBACKEND=Agg
export PATH="$venv/bin:$PATH"
cd "$tmp"
for script in sclam sclam_node; do
  where="$(command -v "$script" || true)"
  if [ "$where" != "$venv/bin/$script" ]; then
    echo "[check] FAIL: $script is not in $venv/bin (found: ${where:-nothing})" >&2
    exit 1
  fi
done
echo "[check] sclam calibrate data/demo/powerbot --urdf robot.urdf"
demo="$root/data/demo/powerbot"
# The parameters file sets laser_*, so they win; the URDF is still read (yourdfpy installed).
cat > robot.urdf <<'URDF'
<robot name="powerbot"><link name="base_link"/><link name="laser"/>
  <joint name="laser_joint" type="fixed"><parent link="base_link"/><child link="laser"/>
    <origin xyz="0.22 0 0.3" rpy="0 0 0"/></joint></robot>
URDF
sclam calibrate "$demo" --params "$demo/params.yaml" --truth "$demo/truth.json" --quiet \
  --urdf robot.urdf --json calibration.json --trajectory run.tum
echo "[check] sclam export calibration.json --format diff-drive / urdf"
sclam export calibration.json --format diff-drive
sclam export calibration.json --format urdf
echo "[check] sclam_node --help"
sclam_node --help
echo "[check] OK: sclam and sclam_node run from a fresh pip install"
