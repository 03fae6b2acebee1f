"""Wheel calibration of the 12 OptiOdom runs against motion capture, and its spread.

    .venv/bin/python bench/optiodom_repeatability.py [DATA_DIR] [--step N]

DATA_DIR defaults to ../shared/data/optiodom-diff beside the repository. Each run is
calibrated on its own (sclam_ros.core.mocap: the mocap marker as a pose sensor with an unknown
mount); the table gives r_l, r_r, b ± σ per run and the mean and standard deviation over
runs (repeatability), against the nominal 42 mm / 42 mm / 200 mm, and how far the wheel
base's regression-dilution correction moved b (or would have, where it is not applied).
"""
import sys
import time
from pathlib import Path

import numpy as np

from sclam_ros.io.convert import optiodom_params, read_optiodom
from sclam_ros.core.mocap import calibrate_with_ground_truth


def _correction(correction) -> str:
    """The wheel base's regression-dilution correction (core/dilution.py): applied, or
    what it would have moved b by where it was not."""
    if correction is None:
        return "–"
    moved = correction["shift_percent"]["wheel_base"]
    return f"{moved:+.2f} %" if correction["applied"] else f"not applied (would be {moved:+.1f} %)"


def main(argv):
    args = [a for a in argv[1:] if not a.startswith("--")]
    step = int(argv[argv.index("--step") + 1]) if "--step" in argv else 10
    if "--step" in argv:
        args.remove(str(step))
    data = Path(args[0]) if args else (
        Path(__file__).resolve().parents[2] / "shared" / "data" / "optiodom-diff")
    runs = sorted(data.glob("*/*/*_run-??.csv"))
    if not runs:
        print(f"no runs under {data}", file=sys.stderr)
        return 1
    params = optiodom_params()
    print(f"keyframe every {step} encoder cycles ({step * 50} ms)")
    print(f"{'run':<22} {'r_l [mm]':>16} {'r_r [mm]':>16} {'b [mm]':>17} "
          f"{'marker yaw [deg]':>17} {'s':>5}  dilution correction of b")
    rows = {"circular": [], "square": []}
    for path in runs:
        stamps, truth, ticks = read_optiodom(path)
        start = time.perf_counter()
        cal = calibrate_with_ground_truth(stamps, ticks, truth, params, step=step)
        seconds = time.perf_counter() - start
        e, s = cal.estimate * 1e3, cal.sigma * 1e3
        shape = path.parent.parent.name
        rows[shape].append(cal.estimate[:3])
        print(f"{shape + ' ' + path.stem[-6:]:<22} {e[0]:8.3f} ± {s[0]:5.3f} {e[1]:8.3f} ± {s[1]:5.3f} "
              f"{e[2]:8.2f} ± {s[2]:5.2f} {np.degrees(cal.estimate[5]):>17.1f} {seconds:5.1f}  "
              f"{_correction(cal.wheel_noise_correction)}")
    everything = np.array(rows["circular"] + rows["square"]) * 1e3
    for name, values in [*rows.items(), ("all", everything / 1e3)]:
        values = np.array(values) * 1e3
        if len(values) == 0:
            continue
        mean, std = values.mean(0), values.std(0, ddof=1)
        print(f"{name + ' mean ± sd':<22} {mean[0]:8.3f} ± {std[0]:5.3f} {mean[1]:8.3f} ± {std[1]:5.3f} "
              f"{mean[2]:8.2f} ± {std[2]:5.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
