"""Skid-steer (issue 59): the effective wheel base and the radii against the simulator's.

The simulated four-wheel skid-steer (`sclam simulate --robot skid`) turns its sides about
centres χ times as far apart as its geometric track (sim/motion.TrueKinematics); its
effective values are the radii and χ times the track. For each χ, over N seeds, the error of
each parameter (%, laser in mm and degrees), its largest, and the RMS of error / reported σ
(honest: 0.7-1.4). The nominal wheel_base is the simulator's (1.5 × the track);
--nominal-track starts it at the geometric track instead.

Run: PYTHONPATH=. .venv/bin/python bench/skid_steer.py [--seeds 10] [--first-seed 100]
     [--duration 120] [--chi 1.5 2.0] [--nominal-track]
"""
import numpy as np
from common import errors, seeds_arguments, simulate_and_calibrate, table

from sclam_ros.core.params import CALIBRATION_KEYS, ODOMETRY_KEYS
from sclam_ros.sim.robots import get_preset

FIRST_SEED = 100  # the test (test/test_skid_steer.py) uses seed 3


def _scaled(key, value, truth):
    """Errors in %, of the truth, for the wheels; mm and degrees for the laser."""
    if key in ODOMETRY_KEYS:
        return 100.0 * value / truth[key], "%"
    return (np.degrees(value), "deg") if key == "laser_yaw" else (1e3 * value, "mm")


def main():
    ap = seeds_arguments(__doc__, 10, 120.0)
    ap.add_argument("--chi", type=float, nargs="+", default=[1.5, 2.0])
    ap.add_argument("--first-seed", type=int, default=FIRST_SEED)
    ap.add_argument("--nominal-track", action="store_true",
                    help="start the wheel base at the geometric track")
    args = ap.parse_args()
    preset = get_preset("skid")
    nominal = {"wheel_base": preset.wheel_separation} if args.nominal_track else None
    rows = []
    for chi in args.chi:
        err, z, unobserved = [], [], 0
        for seed in range(args.first_seed, args.first_seed + args.seeds):
            truth, result, seconds, _ = simulate_and_calibrate(
                "skid", args.duration, seed, nominal_overrides=nominal, track_widening=chi)
            e = errors(truth, result)
            unobserved += not all(result.observable.values())
            err.append([_scaled(k, e[k], truth)[0] for k in CALIBRATION_KEYS])
            z.append([e[k] / result.sigma[k] for k in CALIBRATION_KEYS])
            print(f"χ {chi} seed {seed} ({seconds:.0f} s): error "
                  + " ".join(f"{v:+.3f}" for v in err[-1]) + " | err/σ "
                  + " ".join(f"{v:+.2f}" for v in z[-1]), flush=True)
        err, z = np.array(err), np.array(z)
        for i, key in enumerate(CALIBRATION_KEYS):
            unit = _scaled(key, 1.0, {key: 1.0})[1]
            rows.append([f"{chi:g}", key, f"{np.mean(err[:, i]):+.3f} {unit}",
                         f"{np.sqrt(np.mean(err[:, i] ** 2)):.3f} {unit}",
                         f"{np.max(np.abs(err[:, i])):.3f} {unit}",
                         f"{np.sqrt(np.mean(z[:, i] ** 2)):.2f}"])
        if unobserved:
            print(f"χ {chi}: {unobserved} of {args.seeds} runs left a parameter NOT OBSERVABLE")
    start = "the geometric track" if args.nominal_track else "1.5 × the track"
    print(f"\nskid, {args.seeds} seeds ({args.first_seed}-{args.first_seed + args.seeds - 1}) × "
          f"{args.duration:.0f} s, nominal wheel_base {start}; errors against the simulator's "
          "effective values:")
    print(table(rows, ["χ", "parameter", "mean error", "RMS error", "max |error|", "RMS err/σ"]))


if __name__ == "__main__":
    main()
