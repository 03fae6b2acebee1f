"""Acceptance 1 and 2 of the calibration issue: the paper's table and sensor-offset experiment.

1. For each robot of Kümmerle et al., truth = its first calibrated row, start = nominal,
   5 min at 10 Hz, 360 beams, 1 cm range noise. Targets: radii and base within 0.2 %,
   laser x, y within 1 cm, yaw within 0.3°.
2. Laser truly at (0.3, 0.6, 30°), started from (0, 0, 0): within 1 cm and 0.3°.

Run: .venv/bin/python bench/paper_table.py [--duration 300] [--seed 1]
"""
import argparse
import math

from common import errors, simulate_and_calibrate, table

ROBOTS = ("powerbot", "custom", "pioneer")


def row(name, truth, result, seconds):
    e = errors(truth, result)
    rel = lambda k: 100 * e[k] / truth[k]  # noqa: E731
    ok = (max(abs(rel(k)) for k in ("wheel_radius_left", "wheel_radius_right", "wheel_base")) < 0.2
          and max(abs(e["laser_x"]), abs(e["laser_y"])) < 0.01
          and abs(math.degrees(e["laser_yaw"])) < 0.3)
    return [name, f"{rel('wheel_radius_left'):+.3f}", f"{rel('wheel_radius_right'):+.3f}",
            f"{rel('wheel_base'):+.3f}", f"{1000 * e['laser_x']:+.1f}", f"{1000 * e['laser_y']:+.1f}",
            f"{math.degrees(e['laser_yaw']):+.3f}", f"{seconds:.1f}", "yes" if ok else "NO"]


def main():
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--duration", type=float, default=300.0)
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()
    rows = []
    for robot in ROBOTS:
        truth, result, seconds, _ = simulate_and_calibrate(robot, args.duration, args.seed)
        rows.append(row(f"{robot} (paper row 1)", truth, result, seconds))
    truth, result, seconds, _ = simulate_and_calibrate(
        "powerbot", args.duration, args.seed,
        true_overrides={"laser_x": 0.3, "laser_y": 0.6, "laser_yaw": math.radians(30)},
        nominal_overrides={"laser_x": 0.0, "laser_y": 0.0, "laser_yaw": 0.0})
    rows.append(row("powerbot, laser (0.3, 0.6, 30°) from 0", truth, result, seconds))
    print(f"Errors of the estimate against the truth ({args.duration:.0f} s, seed {args.seed}):")
    print(table(rows, ["recording", "r_l err %", "r_r err %", "b err %", "l_x err mm",
                       "l_y err mm", "l_yaw err °", "calib. s", "within targets"]))


if __name__ == "__main__":
    main()
