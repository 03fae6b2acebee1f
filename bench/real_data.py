"""Real data in one run: the Freiburg ACES log against its ground-truth relations, the
agreement of its two halves, and the Mines rover's run-to-run and half-versus-half agreement.

ACES (../shared/data/freiburg-aces, CC-BY-3.0, Kümmerle et al. 2009) is converted with
`sclam convert carmen` (wheel rotations implied from the logged odometry with a nominal
radius of 0.1 m and wheel base of 0.4 m, laser at the origin as the log's PARAM says) and
calibrated as `sclam calibrate` does. Error = the relation metric of the benchmark: for
each relation, the trajectory's relative pose against the true one; mean ± standard
deviation of the translation (m) and rotation (deg) errors, over spans of 10 s or more and
under 10 s. Rows: the log's own odometry; wheel odometry (the implied wheel rotations
dead-reckoned) with the nominal and the calibrated radii and wheel base; and the graph's
optimised poses (wheels + laser), dead-reckoned between its keyframes. Each scan is
stamped as logged and 0.1 s earlier (the relations' times, which are the scans', with it).

Run: .venv/bin/python bench/real_data.py [DATA_DIR] [--skip-mines]
"""
from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import scratch_dir, table  # noqa: E402

from sclam_ros.core import se2  # noqa: E402
from sclam_ros.core.estimator import calibrate_keyframes  # noqa: E402
from sclam_ros.core.params import CALIBRATION_KEYS, ODOMETRY_KEYS, SclamParams  # noqa: E402
from sclam_ros.io import carmen, relations  # noqa: E402
from sclam_ros.io.convert import convert_carmen  # noqa: E402
from sclam_ros.io.recording import read_recording  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
# s: as logged, and the delay the ground truth's short spans point to (docs/real_data.md)
SCAN_DELAYS = (0.0, 0.1)


def human(key, value):
    return math.degrees(value) if key == "laser_yaw" else 1e3 * value


def relation_rows(log, rel, results, nominal) -> list:
    stamps, poses, _ = carmen.odometry_track(log)
    angles, _ = carmen.implied_wheel_angles(poses, carmen.NOMINAL_RADIUS, carmen.NOMINAL_BASE)
    laser_stamps = np.array([laser.stamp for laser in log.lasers])
    laser_odometry = np.array([laser.robot_pose for laser in log.lasers])
    whole = results["whole"]
    k = [whole.estimate[key] for key in ODOMETRY_KEYS]
    calibrated = relations.wheel_odometry(angles, k)
    trajectories = {
        "the log's odometry": (laser_stamps, laser_odometry),
        "wheels, nominal": (stamps, relations.wheel_odometry(angles, nominal)),
        "wheels, calibrated": (stamps, calibrated),
        "wheels + laser (graph poses)": (stamps, relations.anchored_odometry(
            whole.stamps, whole.poses, stamps, calibrated)),
    }
    rows = []
    for name, (t, p) in trajectories.items():
        errors = relations.relation_errors(t, p, rel)
        cells = [name]
        for long in (True, False):
            s = errors.summary(long)
            cells += [f"{s['translation_m']:.3f} ± {s['translation_sd_m']:.3f}",
                      f"{s['rotation_deg']:.2f} ± {s['rotation_sd_deg']:.2f}"]
        rows.append(cells)
    return rows


def odometry_ratios(result):
    """(r_l / r_r, b / r_r, their σ) from the calibration's covariance, to first order."""
    r_l, r_r, b = (result.estimate[key] for key in ODOMETRY_KEYS)
    cov = np.asarray(result.covariance)[:3, :3]
    ratio = np.array([1 / r_r, -r_l / r_r ** 2, 0.0])
    base = np.array([0.0, -b / r_r ** 2, 1 / r_r])
    return r_l / r_r, b / r_r, (math.sqrt(ratio @ cov @ ratio), math.sqrt(base @ cov @ base))


def ratios_from_relations(log, rel):
    """The radii's ratio and b / r_r that fit the relations' rotations over spans of 10 s or
    more best (least squares on the wheel odometry implied from the log), with the σ that
    the scatter of those rotations gives them. The heading depends on these two only."""
    from scipy.optimize import least_squares

    stamps, poses, _ = carmen.odometry_track(log)
    angles, _ = carmen.implied_wheel_angles(poses, carmen.NOMINAL_RADIUS, carmen.NOMINAL_BASE)
    long = rel[rel[:, 1] - rel[:, 0] >= relations.LONG_SPAN]

    def rotation_errors(q):
        odometry = relations.wheel_odometry(angles, [q[0], 1.0, q[1]])
        start = relations.interpolate_poses(stamps, odometry, long[:, 0])
        end = relations.interpolate_poses(stamps, odometry, long[:, 1])
        return se2.wrap_angle(se2.between(end, start)[:, 2] - long[:, 4])

    fit = least_squares(rotation_errors, [1.0, carmen.NOMINAL_BASE / carmen.NOMINAL_RADIUS],
                        x_scale=[1e-3, 1e-2])
    cov = np.linalg.inv(fit.jac.T @ fit.jac) * np.mean(fit.fun ** 2)
    return fit.x, np.sqrt(np.diag(cov))


def aces(data: Path, work: Path, scan_delay: float) -> None:
    """The scans stamped ``scan_delay`` s before their log lines, and the relations' times
    (the scans') with them."""
    src = data / "freiburg-aces" / "aces.clf.bz2"
    out = work / f"aces_{scan_delay * 1e3:.0f}ms"
    convert_carmen(src, out, scan_delay=scan_delay)
    params = SclamParams.from_yaml(out / "params.yaml")
    recording = read_recording(out / "bag", params)
    keyframes = recording.keyframes
    half = len(keyframes) // 2
    results = {"whole": calibrate_keyframes(keyframes, params, recording.rejections),
               "1st half": calibrate_keyframes(keyframes[:half], params),
               "2nd half": calibrate_keyframes(keyframes[half:], params)}
    report = recording.frontend.report()
    print(f"\n## ACES, scans stamped {scan_delay * 1e3:.0f} ms before their log lines\n")
    print(f"{len(keyframes)} scans matched; {report.matches} matches, "
          f"{report.confirmed} confirmed (not used: {report.unconfirmed}); "
          f"laser judged {'noisy' if report.noisy_laser else 'quiet'} "
          f"({1e3 * report.range_noise:.0f} mm)")
    rows = [[label] + [f"{human(key, r.estimate[key]):.2f} ± {human(key, r.sigma[key]):.2f}"
                       + ("" if r.observable[key] else " (n/o)") for key in CALIBRATION_KEYS]
            + [str(r.converged)] for label, r in results.items()]
    print(table(rows, ["ACES calibration", *CALIBRATION_KEYS, "converged"]))
    a, b = results["1st half"], results["2nd half"]
    z = [(a.estimate[key] - b.estimate[key]) / math.hypot(a.sigma[key], b.sigma[key])
         for key in CALIBRATION_KEYS]
    print(table([["1st − 2nd half"] + [f"{v:+.1f}" for v in z]],
                ["difference / combined σ", *CALIBRATION_KEYS]))
    log = carmen.read_carmen(src)
    rel = relations.read_relations(data / "freiburg-aces" / "aces.relations")
    rel[:, :2] -= scan_delay
    truth, truth_sigma = ratios_from_relations(log, rel)
    rows = [[label, f"{ratio:.5f} ± {sigma[0]:.5f}", f"{(ratio - truth[0]) / sigma[0]:+.1f}",
             f"{base_ratio:.4f} ± {sigma[1]:.4f}", f"{(base_ratio - truth[1]) / sigma[1]:+.1f}"]
            for label, r in results.items()
            for ratio, base_ratio, sigma in [odometry_ratios(r)]]
    rows.append(["relations ≥ 10 s (fit)", f"{truth[0]:.5f} ± {truth_sigma[0]:.5f}", "",
                 f"{truth[1]:.4f} ± {truth_sigma[1]:.4f}", ""])
    print("\nWhat the heading drift depends on: the radii's ratio and the wheel base in right "
          "radii,\nagainst a fit of both to the ground truth's rotations over spans of 10 s or more")
    print(table(rows, ["calibration", "r_l / r_r", "(− fit) / σ", "b / r_r", "(− fit) / σ"]))
    nominal = [carmen.NOMINAL_RADIUS, carmen.NOMINAL_RADIUS, carmen.NOMINAL_BASE]
    print("\nACES relations, mean ± sd of the error")
    print(table(relation_rows(log, rel, results, nominal),
                ["trajectory", "≥ 10 s: translation m", "≥ 10 s: rotation deg",
                 "< 10 s: translation m", "< 10 s: rotation deg"]))


def main(argv) -> int:
    args = [a for a in argv[1:] if not a.startswith("--")]
    data = Path(args[0]) if args else ROOT.parent / "shared" / "data"
    work = scratch_dir("real_data_")
    if (data / "freiburg-aces" / "aces.clf.bz2").exists():
        for delay in SCAN_DELAYS:
            aces(data, work, delay)
    else:
        print(f"freiburg-aces not found under {data}; skipped")
    if "--skip-mines" not in argv:
        import mines_agreement
        print()
        mines_agreement.main([argv[0], str(data)])
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
