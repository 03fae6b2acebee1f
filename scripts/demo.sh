#!/usr/bin/env bash
# Set up .venv if needed, then calibrate the bundled demo recording (a simulated PowerBot,
# see data/demo/README.md) and print the estimates beside the ground truth.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
bash "$root/scripts/setup_venv.sh"
source "$root/scripts/env.sh"
out="${1:-$root/out/demo}"
mkdir -p "$out"
sclam calibrate "$root/data/demo/powerbot" --params "$root/data/demo/powerbot/params.yaml" \
  --truth "$root/data/demo/powerbot/truth.json" --json "$out/calibration.json" --report "$out"
echo "report and JSON written to $out"
