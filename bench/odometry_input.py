"""Calibration from /odom alone (`--wheels odom`: the base's wheel odometry integrated with the
nominal values) against the simulator's truth, PowerBot, default sensor, seeds 1..N.

    PYTHONPATH=. python bench/odometry_input.py --seeds 6 --duration 300   # docs/robot_inputs.md
"""
import math

from common import errors, seeds_arguments, simulate_and_calibrate, table

from sclam_ros.core.params import CALIBRATION_KEYS


def main():
    args = seeds_arguments(__doc__, seeds=6, duration=300.0).parse_args()
    rows = []
    for seed in range(1, args.seeds + 1):
        truth, result, _, _ = simulate_and_calibrate("powerbot", args.duration, seed, wheels="odom")
        e = errors(truth, result)
        rows.append([seed, *(f"{100 * e[k] / truth[k]:+.2f}" for k in CALIBRATION_KEYS[:3]),
                     f"{1e3 * e['laser_x']:+.1f}", f"{1e3 * e['laser_y']:+.1f}",
                     f"{math.degrees(e['laser_yaw']):+.3f}"])
    print(table(rows, ["seed", "r_l %", "r_r %", "b %", "laser_x mm", "laser_y mm",
                       "laser_yaw deg"]))


if __name__ == "__main__":
    main()
