"""The example fleet of docs/fleet.md: two robots, five 60 s recordings each, two real changes.

robot_a's left tyre grows by 2 % before its day 3 (a new tyre); robot_b's laser is knocked by
1° in yaw before its day 4. Runs `sclam fleet` and `sclam fleet report` on them as a user would
and copies the report's figure to docs/figures/fleet_history.png. The report must flag exactly
those two changes.

Run: .venv/bin/python bench/fleet_example.py [--out /tmp/example_fleet]
"""
import argparse
import math
import shutil
import subprocess
from pathlib import Path

from sclam_ros.sim import simulate

DOCS_FIGURE = Path(__file__).resolve().parents[1] / "docs" / "figures" / "fleet_history.png"


def main():
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default="/tmp/example_fleet")
    args = ap.parse_args()
    root = Path(args.out)
    for day in range(1, 6):
        truth = simulate(root / "fleet" / "robot_a" / f"day{day}", duration=60, seed=10 + day,
                         overwrite=True, true_overrides={
                             "wheel_radius_left": 0.1263 * (1.02 if day >= 3 else 1.0)})
        knocked = math.radians(1.0) if day >= 4 else 0.0
        simulate(root / "fleet" / "robot_b" / f"day{day}", duration=60, seed=20 + day,
                 overwrite=True, true_overrides={"laser_yaw": truth["laser_yaw"] + knocked})
    results = root / "results"
    subprocess.run(["sclam", "fleet", str(root / "fleet"), "--out", str(results)], check=True)
    subprocess.run(["sclam", "fleet", "report", str(results)], check=True)
    shutil.copy(results / "history.png", DOCS_FIGURE)
    print(f"figure copied to {DOCS_FIGURE}")


if __name__ == "__main__":
    main()
