"""The real data sets in one script, as sections (--only aces,mines,censi,optiodom; default
all), each printing the tables docs/real_data.md quotes. DATA_DIR (default ../shared/data
beside the repository) holds one folder per data set, read in place; an absent one is
skipped with a message.

aces: the Freiburg ACES log against its ground-truth relations, and the agreement of its
two halves. ACES (freiburg-aces, CC-BY-3.0, Kümmerle et al. 2009) is converted with
`sclam convert carmen` (wheel rotations implied from the logged odometry with a nominal
radius of 0.1 m and wheel base of 0.4 m, laser at the origin as the log's PARAM says) and
calibrated as `sclam calibrate` does. Error = the relation metric of the benchmark: for
each relation, the trajectory's relative pose against the true one; mean ± standard
deviation of the translation (m) and rotation (deg) errors, over spans of 10 s or more and
under 10 s. Rows: the log's own odometry; wheel odometry (the implied wheel rotations
dead-reckoned) with the nominal and the calibrated radii and wheel base; and the graph's
optimised poses (wheels + laser), dead-reckoned between its keyframes. Each scan is
stamped as logged and 0.1 s earlier (the relations' times, which are the scans', with it).

mines: run-to-run and half-versus-half agreement on the real Mines rover (URG-04LX), in σ.
The two breezyslam-mines runs (LGPL-3.0; converted with `sclam convert breezyslam`, each
scan stamped 160 ms before its log line as docs/real_data.md establishes) are calibrated
whole and in halves (the first and second half of the run's scans, each calibrated alone).
With no ground truth, agreement is the test of honesty: two calibrations of one robot
should differ by about their combined σ, z = (a − b) / sqrt(σa² + σb²), |z| > 3 rarely.

censi: Censi et al.'s Khepera III tuples (censi-khepera-tuples; no licence, never copied)
calibrated with our graph: per laser mounting, our estimate ± marginal σ beside the
published one ± its σ (radii = diameters / 2), the distance in published σ, the
down-weighted scan matches and the wall time.

optiodom: wheel calibration of the 12 OptiOdom runs (optiodom-diff) against motion capture,
and its spread. Each run is calibrated on its own (sclam_ros.core.mocap: the mocap marker as
a pose sensor with an unknown mount), one keyframe every --step encoder cycles; the table
gives r_l, r_r, b ± σ per run and the mean and standard deviation over runs
(repeatability), against the nominal 42 mm / 42 mm / 200 mm, and how far the wheel base's
regression-dilution correction moved b (or would have, where it is not applied).

Run: .venv/bin/python bench/real_data.py [DATA_DIR] [--only aces,mines,censi,optiodom] [--step 10]
"""
from __future__ import annotations

import argparse
import itertools
import math
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import scratch_dir, table  # noqa: E402

from sclam_ros.core import kinematics, se2  # noqa: E402
from sclam_ros.core.estimator import calibrate_keyframes  # noqa: E402
from sclam_ros.core.params import CALIBRATION_KEYS, ODOMETRY_KEYS, SclamParams  # noqa: E402
from sclam_ros.core.mocap import calibrate_with_ground_truth  # noqa: E402
from sclam_ros.io import carmen, censi, relations  # noqa: E402
from sclam_ros.io.convert import (  # noqa: E402
    convert_breezyslam, convert_carmen, optiodom_params, read_optiodom)
from sclam_ros.io.recording import read_recording  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SECTIONS = ("aces", "mines", "censi", "optiodom")
# s: as logged, and the delay the ground truth's short spans point to (docs/real_data.md)
SCAN_DELAYS = (0.0, 0.1)
MINES_SCAN_DELAY = 0.16  # s, docs/real_data.md
CENSI_NAMES = ("r_l [mm]", "r_r [mm]", "b [mm]", "l_x [mm]", "l_y [mm]", "l_yaw [deg]")
CENSI_SCALE = np.array([1e3, 1e3, 1e3, 1e3, 1e3, 180 / np.pi])


def human(key, value):
    return math.degrees(value) if key == "laser_yaw" else 1e3 * value


def relation_rows(log, rel, results, nominal, fitted) -> list:
    """fitted: {label: (r_l / r_r, b / r_r)} fitted to the relations, each made into wheels
    with the calibrated r_r (the heading does not depend on the scale)."""
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
    for label, (ratio, base_ratio) in fitted.items():
        trajectories[f"wheels, ratios fit to the relations {label}"] = (
            stamps, relations.wheel_odometry(angles, [ratio * k[1], k[1], base_ratio * k[1]]))
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


def ratios_from_relations(log, rel, long=True):
    """The radii's ratio and b / r_r that fit the relations' rotations over spans of 10 s or
    more (long) or under 10 s best (least squares on the wheel odometry implied from the
    log), with the σ that the scatter of those rotations gives them. The heading depends on
    these two only."""
    from scipy.optimize import least_squares

    stamps, poses, _ = carmen.odometry_track(log)
    angles, _ = carmen.implied_wheel_angles(poses, carmen.NOMINAL_RADIUS, carmen.NOMINAL_BASE)
    span = rel[:, 1] - rel[:, 0]
    long = rel[span >= relations.LONG_SPAN] if long else rel[span < relations.LONG_SPAN]

    def rotation_errors(q):
        odometry = relations.wheel_odometry(angles, [q[0], 1.0, q[1]])
        start = relations.interpolate_poses(stamps, odometry, long[:, 0])
        end = relations.interpolate_poses(stamps, odometry, long[:, 1])
        return se2.wrap_angle(se2.between(end, start)[:, 2] - long[:, 4])

    fit = least_squares(rotation_errors, [1.0, carmen.NOMINAL_BASE / carmen.NOMINAL_RADIUS],
                        x_scale=[1e-3, 1e-2])
    cov = np.linalg.inv(fit.jac.T @ fit.jac) * np.mean(fit.fun ** 2)
    return fit.x, np.sqrt(np.diag(cov))


def base_ratio_of_matches(keyframes, ratio, base_ratio, min_turn=0.05):
    """b / r_r at which the wheels turn as the confirmed scan matches do, match by match
    (least squares of the match's rotation on the wheels' over matches turning more than
    min_turn rad), for all such matches and for left and right turns: what the laser sees
    turn by turn, with r_l / r_r held at `ratio`."""
    wheel, laser = [], []
    for keyframe in keyframes:
        if keyframe.laser_motion is None:
            continue
        dphi = keyframe.wheel_angles - keyframes[keyframe.laser_from].wheel_angles
        wheel.append(kinematics.forward(dphi, np.array([ratio, 1.0, base_ratio]))[2])
        laser.append(keyframe.laser_motion[2])
    wheel, laser = np.array(wheel), np.array(laser)
    out = []
    for pick in (np.abs(wheel) > min_turn, wheel > min_turn, wheel < -min_turn):
        scale = np.sum(laser[pick] * wheel[pick]) / np.sum(wheel[pick] ** 2)
        out.append(base_ratio / scale)
    return out


SPEED_BANDS = ((0.0, 0.05), (0.05, 0.15), (0.15, 0.3), (0.3, 0.5), (0.5, 2.0))  # m/s


def base_ratio_by_speed(keyframes, ratio, base_ratio, min_turn=0.03) -> list:
    """Rows (speed band, turn side, matches, b / r_r at which the wheels turn as the
    confirmed scan matches do, mean |wheel turn|): base_ratio_of_matches within bands of the
    wheels' speed over the match (r_r taken as 1 m: the band edges are in r_r)."""
    turn, seen, speed = [], [], []
    for keyframe in keyframes:
        if keyframe.laser_motion is None:
            continue
        before = keyframes[keyframe.laser_from]
        dphi = keyframe.wheel_angles - before.wheel_angles
        turn.append(kinematics.forward(dphi, np.array([ratio, 1.0, base_ratio]))[2])
        seen.append(keyframe.laser_motion[2])
        speed.append(0.5 * abs(dphi[0] * ratio + dphi[1]) * carmen.NOMINAL_RADIUS
                     / max(keyframe.stamp - before.stamp, 1e-3))
    turn, seen, speed = np.array(turn), np.array(seen), np.array(speed)
    rows = []
    for (low, high), (side, sign) in itertools.product(SPEED_BANDS, (("left", 1), ("right", -1))):
        pick = (speed >= low) & (speed < high) & (sign * turn > min_turn)
        if pick.sum() >= 10:
            scale = np.sum(seen[pick] * turn[pick]) / np.sum(turn[pick] ** 2)
            rows.append([f"{low:.2f}-{high:.2f}", side, int(pick.sum()),
                         f"{base_ratio / scale:.4f}", f"{np.abs(turn[pick]).mean():.3f}"])
    return rows


def aces(data: Path, work: Path, scan_delay: float, fov: float) -> None:
    """The scans stamped ``scan_delay`` s before their log lines, and the relations' times
    (the scans') with them; their beams spread over ``fov`` rad."""
    src = data / "freiburg-aces" / "aces.clf.bz2"
    out = work / f"aces_{scan_delay * 1e3:.0f}ms"
    convert_carmen(src, out, scan_delay=scan_delay, fov=fov)
    params = SclamParams.from_yaml(out / "params.yaml")
    recording = read_recording(out / "bag", params)
    keyframes = recording.keyframes
    half = len(keyframes) // 2
    results = {"whole": calibrate_keyframes(keyframes, params, recording.rejections),
               "1st half": calibrate_keyframes(keyframes[:half], params),
               "2nd half": calibrate_keyframes(keyframes[half:], params)}
    report = recording.frontend.report()
    print(f"\n## ACES, scans stamped {scan_delay * 1e3:.0f} ms before their log lines, "
          f"beams over {math.degrees(fov):.1f}°\n")
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
    short, short_sigma = ratios_from_relations(log, rel, long=False)
    rows.append(["relations ≥ 10 s (fit)", f"{truth[0]:.5f} ± {truth_sigma[0]:.5f}", "",
                 f"{truth[1]:.4f} ± {truth_sigma[1]:.4f}", ""])
    rows.append(["relations < 10 s (fit)", f"{short[0]:.5f} ± {short_sigma[0]:.5f}",
                 f"{(short[0] - truth[0]) / short_sigma[0]:+.1f}",
                 f"{short[1]:.4f} ± {short_sigma[1]:.4f}",
                 f"{(short[1] - truth[1]) / short_sigma[1]:+.1f}"])
    print("\nWhat the heading drift depends on: the radii's ratio and the wheel base in right "
          "radii,\nagainst a fit of both to the ground truth's rotations over spans of 10 s or more")
    print(table(rows, ["calibration", "r_l / r_r", "(− fit) / σ", "b / r_r", "(− fit) / σ"]))
    nominal = [carmen.NOMINAL_RADIUS, carmen.NOMINAL_RADIUS, carmen.NOMINAL_BASE]
    print("\nACES relations, mean ± sd of the error")
    every, left, right = base_ratio_of_matches(keyframes, *truth)
    print(f"The confirmed scan matches, turn by turn (r_l / r_r at the ≥ 10 s fit): "
          f"b / r_r = {every:.4f} (left turns {left:.4f}, right turns {right:.4f})")
    print("\nThe same by the wheels' speed over the match (nominal radius), turns over 0.03 rad")
    print(table(base_ratio_by_speed(keyframes, *truth),
                ["speed m/s", "turn", "matches", "b / r_r", "mean |turn| rad"]))
    fitted = {"≥ 10 s": truth, "< 10 s": short}
    print(table(relation_rows(log, rel, results, nominal, fitted),
                ["trajectory", "≥ 10 s: translation m", "≥ 10 s: rotation deg",
                 "< 10 s: translation m", "< 10 s: rotation deg"]))


def run_aces(data: Path, work: Path, fov: float) -> None:
    if not (data / "freiburg-aces" / "aces.clf.bz2").exists():
        print(f"freiburg-aces not found under {data}; skipped")
        return
    for delay in SCAN_DELAYS:
        aces(data, work, delay, fov)


def mines_calibrations(src: Path, work: Path) -> dict:
    """{label: CalibrationResult} for the whole Mines run and its two halves."""
    out = work / src.stem
    convert_breezyslam(src, out, scan_delay=MINES_SCAN_DELAY)
    params = SclamParams.from_yaml(out / "params.yaml")
    keyframes = read_recording(out / "bag", params).keyframes
    half = len(keyframes) // 2
    # The graph keeps only edges between the keyframes it is given: the second half's first
    # edges, which start in the first half, are left out.
    return {
        f"{src.stem} whole": calibrate_keyframes(keyframes, params),
        f"{src.stem} 1st half": calibrate_keyframes(keyframes[:half], params),
        f"{src.stem} 2nd half": calibrate_keyframes(keyframes[half:], params),
    }


def run_mines(data: Path, work: Path) -> None:
    sources = [data / "breezyslam-mines" / f"exp{n}.dat" for n in (1, 2)]
    if not all(s.exists() for s in sources):
        print(f"breezyslam-mines not found under {data}; nothing to do")
        return
    results = {}
    for src in sources:
        results.update(mines_calibrations(src, work))
    rows = [[label] + [f"{human(k, r.estimate[k]):.2f} ± {human(k, r.sigma[k]):.2f}"
                       + ("" if r.observable[k] else " (n/o)") for k in CALIBRATION_KEYS]
            for label, r in results.items()]
    print(f"Mines rover, scans stamped {MINES_SCAN_DELAY * 1e3:.0f} ms early; mm and degrees, ± 1σ")
    print(table(rows, ["calibration", *CALIBRATION_KEYS]))
    pairs = [("exp1 whole", "exp2 whole"), ("exp1 1st half", "exp1 2nd half"),
             ("exp2 1st half", "exp2 2nd half")]
    pairs += [(a, b) for a, b in itertools.product(["exp1 1st half", "exp1 2nd half"],
                                                     ["exp2 1st half", "exp2 2nd half"])]
    rows = []
    for a, b in pairs:
        ra, rb = results[a], results[b]
        cells = []
        for k in CALIBRATION_KEYS:
            if not (ra.observable[k] and rb.observable[k]):
                cells.append("n/o")
                continue
            z = (ra.estimate[k] - rb.estimate[k]) / math.hypot(ra.sigma[k], rb.sigma[k])
            cells.append(f"{z:+.1f}")
        rows.append([f"{a} − {b}", *cells])
    print("\ndifference / combined σ (n/o: not observable in one of them)")
    print(table(rows, ["pair", *CALIBRATION_KEYS]))
    zs = [abs(float(c)) for row in rows for c in row[1:] if c != "n/o"]
    print(f"\n|z| > 2: {sum(z > 2 for z in zs)} of {len(zs)}; |z| > 3: {sum(z > 3 for z in zs)} of {len(zs)}")


def run_censi(data: Path) -> None:
    data = data / "censi-khepera-tuples"
    if not data.is_dir():
        print(f"{data} not found; skipped")
        return
    worst = 0.0
    for mounting in censi.MOUNTINGS:
        tuples = censi.load_tuples(data / f"{mounting}.tuple")
        published, cov = censi.load_published(data / f"{mounting}_results.json")
        start = time.perf_counter()
        ours = censi.calibrate_tuples(tuples)
        seconds = time.perf_counter() - start
        z = censi.compare(ours, published, cov)
        worst = max(worst, float(z.max()))
        print(f"\n{mounting}: {len(tuples)} tuples, {ours.downweighted} scan matches "
              f"down-weighted (robust weight < {censi.DOWNWEIGHT_WEIGHT}), "
              f"start yaw {np.degrees(ours.nominal[5]):.1f} deg, {seconds:.1f} s, "
              f"variance scales {', '.join(f'{k} {v:.3g}' for k, v in ours.variance_scales.items())}")
        print(f"  {'parameter':<12} {'ours ± σ':>22} {'Censi 2013 ± σ':>22} {'|Δ|/σ_pub':>10}")
        for i, name in enumerate(CENSI_NAMES):
            s = CENSI_SCALE[i]
            print(f"  {name:<12} {ours.estimate[i] * s:>12.3f} ± {ours.sigma[i] * s:<7.3f}"
                  f" {published[i] * s:>12.3f} ± {np.sqrt(cov[i, i]) * s:<7.3f} {z[i]:>10.2f}")
    print(f"\nworst |Δ| = {worst:.2f} published σ")


def _dilution_correction(correction) -> str:
    """The wheel base's regression-dilution correction (core/dilution.py): applied, or
    what it would have moved b by where it was not."""
    if correction is None:
        return "–"
    moved = correction["shift_percent"]["wheel_base"]
    return f"{moved:+.2f} %" if correction["applied"] else f"not applied (would be {moved:+.1f} %)"


def run_optiodom(data: Path, step: int) -> None:
    data = data / "optiodom-diff"
    runs = sorted(data.glob("*/*/*_run-??.csv"))
    if not runs:
        print(f"no runs under {data}; skipped")
        return
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
              f"{_dilution_correction(cal.wheel_noise_correction)}")
    everything = np.array(rows["circular"] + rows["square"])
    for name, values in [*rows.items(), ("all", everything)]:
        values = np.array(values) * 1e3
        if len(values) == 0:
            continue
        mean, std = values.mean(0), values.std(0, ddof=1)
        print(f"{name + ' mean ± sd':<22} {mean[0]:8.3f} ± {std[0]:5.3f} {mean[1]:8.3f} ± {std[1]:5.3f} "
              f"{mean[2]:8.2f} ± {std[2]:5.2f}")


def main(argv) -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("data", nargs="?", type=Path, default=ROOT.parent / "shared" / "data",
                    help="the folder holding one folder per data set")
    ap.add_argument("--only", default=",".join(SECTIONS),
                    help=f"comma-separated sections to run, of {','.join(SECTIONS)}")
    ap.add_argument("--aces-fov", type=float, default=math.degrees(carmen.FLASER_FOV),
                    metavar="DEG", help="aces: the span of the FLASER beams (the log does "
                                        "not state it; sclam convert carmen --fov)")
    ap.add_argument("--step", type=int, default=10,
                    help="optiodom: a keyframe every STEP encoder cycles")
    args = ap.parse_args(argv[1:])
    chosen = [name.strip() for name in args.only.split(",") if name.strip()]
    unknown = sorted(set(chosen) - set(SECTIONS))
    if unknown:
        ap.error(f"unknown section(s) {', '.join(unknown)}; choose from {', '.join(SECTIONS)}")
    work = scratch_dir("real_data_")
    run = {"aces": lambda: run_aces(args.data, work, math.radians(args.aces_fov)),
           "mines": lambda: run_mines(args.data, work),
           "censi": lambda: run_censi(args.data),
           "optiodom": lambda: run_optiodom(args.data, args.step)}
    for i, name in enumerate(name for name in SECTIONS if name in chosen):
        if i:
            print()
        run[name]()
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
