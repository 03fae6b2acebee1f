"""``sclam calibrate BAG [--params PARAMS.yaml]``: the six calibration parameters of a recording.

Reads wheel encoder ticks (sensor_msgs/JointState) and laser scans (sensor_msgs/LaserScan)
from a rosbag2 (sqlite3 or mcap), registers consecutive scans with KISS-ICP, and estimates
the wheel radii, the wheel base and the laser pose jointly with all robot poses in one
graph. Prints estimate, 1σ, nominal and change; --json and --report write files.
"""
from __future__ import annotations

import argparse
import json
import logging
import math
from pathlib import Path

from sclam_ros.core.params import CALIBRATION_KEYS
from sclam_ros.frontend.config import DecimationConfig

log = logging.getLogger("sclam")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("bag", help="rosbag2 folder, or its .db3 / .mcap file")
    parser.add_argument("--params", metavar="PARAMS.yaml",
                        help="ROS 2 parameters file for node 'sclam' (topics, joints, nominal "
                             "values); without it they are inferred from the recording's "
                             "topics, /robot_description (or --urdf) and /tf_static, printed, "
                             "and written to --save-params")
    parser.add_argument("--save-params", metavar="OUT.yaml",
                        help="without --params: where to write the inferred parameters "
                             "(default: BAGNAME.params.yaml in the current folder)")
    parser.add_argument("--urdf", metavar="ROBOT.urdf",
                        help="take the nominal laser pose (x, y, yaw) from this URDF: the chain "
                             "of fixed joints from base_frame to the scan's frame_id, instead of "
                             "the recording's /tf_static; laser_x, laser_y, laser_yaw set in "
                             "the parameters file still win; without --params, also the wheel "
                             "joints, radius and separation instead of /robot_description")
    parser.add_argument("--json", metavar="OUT.json", help="write the estimate and σ as JSON")
    parser.add_argument("--report", metavar="DIR", help="write figures (trajectories, residuals) here")
    parser.add_argument("--trajectory", metavar="OUT.tum",
                        help="write the optimised poses in TUM format (for evo) and, beside it, "
                             "OUT.nominal.tum and OUT.calibrated.tum (wheel odometry with the "
                             "nominal and the calibrated parameters) and OUT.truth.tum when the "
                             "recording has ground truth (batch solve; not with --track)")
    parser.add_argument("--truth", metavar="truth.json",
                        help="true values to print beside the estimate: the truth.json of `sclam simulate`, "
                             "or a JSON object of the six values (parameter names, or r_l, r_r, "
                             "b, l_x, l_y, l_yaw) under 'true'")
    parser.add_argument("--track", metavar="OUT.csv",
                        help="instead of the batch solve, run the online calibrator of sclam_node "
                             "(sliding window) over the recording as fast as it can and write its "
                             "estimates over time: t (s, header stamp), the six parameters, "
                             "sigma_<name> and observable_<name> (1 or 0: a parameter the data "
                             "has not observed is at its nominal value) for each")
    parser.add_argument("--workers", type=_workers, default="auto", metavar="auto|N",
                        help="register the recording in N time chunks in parallel, one local "
                             "process each, joined in one graph; 1: sequentially. Default "
                             "auto: one chunk per core when the recording is long enough "
                             "for it to pay (two minutes or more), else sequentially; the "
                             "choice is logged")
    parser.add_argument("--scheduler", metavar="tcp://HOST:8786",
                        help="register the chunks on this existing Dask cluster instead (one "
                             "per worker of the cluster, or --workers N)")
    parser.add_argument("--quiet", action="store_true", help="no progress output")
    parser.add_argument("--verbose", action="store_true", help="log every solver iteration")


def _human(key, value):
    """Value in the unit a person reads: mm for lengths, degrees for the yaw (labelled)."""
    return (math.degrees(value), "deg") if key == "laser_yaw" else (1000.0 * value, "mm")


def format_table(result, truth=None) -> str:
    header = f"{'parameter':<20}{'estimate':>12}{'1σ':>10}{'nominal':>12}{'change':>11}"
    if truth:
        header += f"{'truth':>12}{'error':>10}{'err/σ':>7}"
    lines = [header + "  unit", "-" * len(header)]
    for key in CALIBRATION_KEYS:
        est, unit = _human(key, result.estimate[key])
        sig, _ = _human(key, result.sigma[key])
        nom, _ = _human(key, result.nominal[key])
        row = f"{key:<20}{est:>12.3f}{sig:>10.3f}{nom:>12.3f}{est - nom:>+11.3f}"
        if truth:
            tru, _ = _human(key, truth[key])
            row += f"{tru:>12.3f}{est - tru:>+10.3f}{(est - tru) / sig:>+7.1f}"
        flag = "" if result.observable[key] else "  NOT OBSERVABLE"
        lines.append(row + f"  {unit}{flag}")
    return "\n".join(lines)


TRACK_COLUMNS = ("t", *CALIBRATION_KEYS, *(f"sigma_{k}" for k in CALIBRATION_KEYS),
                 *(f"observable_{k}" for k in CALIBRATION_KEYS))


class _KeepingKeyframes:
    """An OnlineCalibrator fed as the node feeds it, with the per-scan keyframes its front
    end makes kept aside: the wiring check needs the whole recording's motion, which the
    sliding window forgets (a keyframe holds no scan points: ~1 kB each)."""

    def __init__(self, calibrator):
        self.calibrator = calibrator
        self.rejections = calibrator.rejections
        self.keyframes = []

    def add_encoder(self, stamp, left_raw, right_raw):
        return self._add(self.calibrator.frontend.add_encoder(stamp, left_raw, right_raw))

    def add_scan(self, scan):
        return self._add(self.calibrator.frontend.add_scan(scan))

    def _add(self, keyframes):
        self.keyframes += keyframes
        return self.calibrator.add_keyframes(keyframes)


def track(bag, params, progress=None):
    """Feed a recording through the node's OnlineCalibrator in record order, as fast as it can.

    Returns (rows, calibrator, keyframes): one row per window solve, in TRACK_COLUMNS order,
    and the per-scan keyframes the calibrator was given.
    """
    from sclam_ros.io.recording import iter_outputs
    from sclam_ros.online.calibrator import OnlineCalibrator

    calibrator = OnlineCalibrator(params)
    sink = _KeepingKeyframes(calibrator)
    rows = []

    def record(estimate):
        if estimate is not None:
            rows.append([estimate.stamp, *(estimate.values[k] for k in CALIBRATION_KEYS),
                         *(estimate.sigma[k] for k in CALIBRATION_KEYS),
                         *(int(estimate.observable[k]) for k in CALIBRATION_KEYS)])

    # The messages in record order through the same calls the node makes in its callbacks.
    for estimate in iter_outputs(bag, params, sink, progress):
        record(estimate)
    # No flush at the end: the live node never sees an end either, so both stop at the
    # same last estimate.
    return rows, calibrator, sink.keyframes


def write_track(path, rows) -> None:
    from sclam_ros.core.params import atomic_write_text

    lines = [",".join(TRACK_COLUMNS)]
    lines += [f"{row[0]:.6f}," + ",".join(f"{v:.9g}" for v in row[1:]) for row in rows]
    atomic_write_text(path, "\n".join(lines) + "\n")


def _run_track(args, params, truth) -> int:
    from types import SimpleNamespace

    from sclam_ros.cli.progress import ProgressBar

    from sclam_ros.core.estimator import CalibrationError, check_wiring

    rows, calibrator, keyframes = track(args.bag, params,
                                        ProgressBar("online calibration", not args.quiet))
    report = calibrator.frontend.report()
    _warn_about_input(calibrator.rejections, report)
    # The batch solve's refusal, on the same keyframes: the window would absorb swapped or
    # backwards encoders into absurd values with small σ.
    check_wiring(keyframes, params)
    estimate = calibrator.estimate
    if estimate is None:  # refused before writing: exit status 2 leaves no output behind
        raise CalibrationError("the online calibrator produced no estimate (too little motion, "
                               "or no scans paired with encoder data). Rejections: "
                               f"{calibrator.rejections}")
    write_track(args.track, rows)
    print(f"online: {len(rows)} window solves, window {estimate.window_distance:.1f} m "
          f"({estimate.keyframes_in_window} keyframes); last estimate at t = {estimate.stamp:.3f} s")
    shown = SimpleNamespace(estimate=estimate.values, sigma=estimate.sigma,
                            nominal=dict(zip(CALIBRATION_KEYS, map(float, calibrator.nominal))),
                            observable=estimate.observable)
    print(format_table(shown, truth))
    _explain_unobserved(shown.observable, report)
    print(f"track: {args.track}")
    return 0


def _explain_unobserved(observable, report=None) -> None:
    """Why the flagged parameters kept their nominal value. The decision is the information
    rule's (core/observability.py): the data adds too little information on them. Few
    confirmed scan matches is said beside it where it holds, as a likely contributor, not
    as the decision."""
    if all(observable.values()):
        return
    print("Parameters marked NOT OBSERVABLE kept their nominal value: the recording carries "
          "too little information on them.")
    if report is not None and report.mostly_unconfirmed:
        print(f"Only {report.confirmed} of {report.matches} scan matches could be confirmed "
              "(few straight surfaces in view for this laser's range noise), which leaves the "
              "odometry little to be compared with.")
    else:
        print("What excites them: turns in both directions (the wheel base and the laser "
              "offset), straights (the radii' common scale).")


def _workers(text):
    if text == "auto":
        return text
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected auto or a number of workers ≥ 1, got {text!r}")
    return value


def _register(args, params, progress):
    """The io.recording.Recording of the bag: sequentially, in time chunks on local
    processes (fleet/processes.py), or on the Dask cluster of --scheduler."""
    from sclam_ros.fleet.chunked import recording_of
    from sclam_ros.io import bag
    from sclam_ros.io.recording import read_recording

    if args.scheduler:
        from sclam_ros.fleet.chunked import dask_results
        from sclam_ros.fleet.engine import dask_client

        with dask_client(scheduler=args.scheduler, dashboard=not args.quiet) as client:
            workers = len(client.scheduler_info()["workers"])
            chunks = workers if args.workers == "auto" else args.workers
            return recording_of(dask_results(client, args.bag, params, chunks, progress))
    from sclam_ros.fleet.processes import registered_in_parallel
    from sclam_ros.fleet.workers import choose_workers

    choice = choose_workers(args.workers, bag.duration_s(args.bag))
    log.info("%s", choice.reason)
    if choice.workers == 1:
        return read_recording(args.bag, params, progress=progress)
    return registered_in_parallel(args.bag, params, choice.workers, progress)


# Rejections that every recording has: the first scans of each local map only build it.
EXPECTED_REJECTIONS = {"match_map_warmup"}


def _warn_about_input(rejections, report) -> None:
    """Say what the data path dropped or could not refine, so nothing is lost silently.
    ``report``: the front end's FrontendReport (joined over the chunks where the keyframes
    were made in chunks)."""
    # The scans that build each new local map (the first few of a recording) are not matched
    # by design: an info, so that a clean recording ends without a warning.
    # match_unconfirmed gets its own warning below, with its reasons.
    unexpected = {r: n for r, n in rejections.counts.items()
                  if r not in EXPECTED_REJECTIONS and r != "match_unconfirmed"}
    expected = {r: n for r, n in rejections.counts.items() if r in EXPECTED_REJECTIONS}
    if unexpected:
        log.warning("rejected input (counted, not used): %s",
                    ", ".join(f"{r}: {n}" for r, n in sorted(unexpected.items())))
    if expected:
        log.info("not used by design: %s", ", ".join(f"{r}: {n}" for r, n in sorted(expected.items())))
    if report is None:
        return
    if report.skipped_scans:
        log.info("%d scans not matched by design: 1 scan in %d is, about %g s apart%s "
                 "(sclam_ros/frontend/decimation.py)", report.skipped_scans,
                 report.match_every, report.match_period,
                 ", and the scan after each encoder sample (the encoders are slower)"
                 if report.matches_follow_samples else "")
    if report.odometry_guess_failures:
        log.warning("%d scan(s) could only be registered from the previous scan's motion: "
                    "from the wheel odometry's prediction (nominal calibration) the registration "
                    "failed (nominal values far off, the encoders wired wrong, or little "
                    "structure in view)", report.odometry_guess_failures)
    if report.odometry_guess_overruled:
        # Outdoors the overlap that decides is noisy; wiring errors are refused elsewhere.
        log.info("%d scan(s) registered from the previous scan's motion, which the previous "
                 "scan confirmed better than the wheel odometry's prediction",
                 report.odometry_guess_overruled)
    if report.noisy_laser:
        log.info("noisy laser (range noise %.0f mm measured on its first scans, from %.0f mm "
                 "on): wall lines fitted to whole straight segments instead of %d beams",
                 1e3 * report.range_noise, 1e3 * report.noisy_from, report.line_beams)
    if report.range_noise_growth:
        log.info("the laser's range noise grows with range (by %.0f %% of its value at 0 m per "
                 "metre, measured on its first scans): returns weighed by 1/σ(range)²",
                 100.0 * report.range_noise_growth)
    unconfirmed = report.unconfirmed
    if unconfirmed:
        # KISS-ICP's motion alone is biased where the refinement fails (point_to_line.py).
        log.warning("%d of %d scan matches not used: the point-to-line refinement could not "
                    "confirm them (%s; few straight walls in view: an outdoor scene?)",
                    sum(unconfirmed.values()), report.matches,
                    ", ".join(f"{UNREFINED_REASONS[r]}: {n}"
                              for r, n in sorted(unconfirmed.items())))
    if report.sigma_may_be_small:
        log.warning("with a noisy laser and most scan matches unconfirmed the reported σ may "
                    "be too small: outdoors on the simulator the errors were up to 1.6 σ RMS for "
                    "the wheels and 2.4 σ for the laser yaw (docs/accuracy.md)")


UNREFINED_REASONS = {
    "no_lines": "too few points on lines",
    "too_few_pairs": "too few points near a line",
    "correction_too_large": "it would move KISS-ICP's answer by more than 5 cm",
}


class _Warnings(logging.Handler):
    """Every warning logged during the run, one line each, for --json (the same ones reach
    stderr through the command's log handler)."""

    def __init__(self):
        super().__init__(logging.WARNING)
        self.lines = []

    def emit(self, record):
        self.lines.append(" ".join(record.getMessage().split()))


def run(args) -> int:
    """Input errors (ParamsError, BagError, CalibrationError, ...) propagate to
    sclam_ros.cli.main, which turns each into one line and exit status 2."""
    warnings = _Warnings()
    log.addHandler(warnings)
    try:
        return _run(args, warnings.lines)
    finally:
        log.removeHandler(warnings)


def _explain_dilution(correction) -> None:
    """One line on the wheel noise's regression dilution of k (core/dilution.py)."""
    if correction is None:
        return
    shift = correction["shift_percent"]
    moves = ", ".join(f"{k} {v:+.3f} %" for k, v in shift.items())
    if correction["applied"]:
        log.info("corrected for the wheel noise's regression dilution: %s", moves)
    else:
        log.warning("the wheel noise dilutes the odometry parameters on this drive by more than "
                    "a first-order correction can take (it would move them by %s): the drive "
                    "determines them weakly, and they may be off by that much", moves)


def _explain_skid_steer(params, wheel_sides) -> None:
    """A skid-steer's per-side wheel disagreement (frontend/wheel_sides.py; above its
    threshold it was warned about while reading), and a nominal wheel base that is the
    geometric track."""
    if params.wheels_per_side < 2:
        return
    if params.wheel_separation and params.wheel_base <= params.wheel_separation:
        log.warning("skid-steer with the nominal wheel_base (%.3f m) not wider than its "
                    "wheel_separation (%.3f m): the effective wheel base is wider (1.2-2x the "
                    "track); started at the track, the scan matcher's odometry guesses fail in "
                    "turns and the wheel base may be left undetermined (2 of 3 simulated drives "
                    "at 2x, docs/robot_inputs.md#skid-steer): start from 1.5x (wheel_base: %.3f)", params.wheel_base, params.wheel_separation,
                    1.5 * params.wheel_separation)
    for side, values in (wheel_sides or {}).items():
        if values["rms_percent"] is not None:
            print(f"{side} wheels ({', '.join(values['joints'])}): they disagree by "
                  f"{values['rms_percent']:.2f} % RMS of their rotation "
                  f"({values['stretches']} stretches, {values['over']} over the warning level)")


def _inferred(args):
    """The parameters inferred from the recording (io/zero_config.py), printed and written
    as a parameters file the user can edit and pass next time."""
    from sclam_ros.io.zero_config import infer_params, inferred_params_header

    params, lines = infer_params(args.bag, args.urdf)
    out = Path(args.save_params or f"{Path(args.bag).resolve().name}.params.yaml")
    params.write_yaml(out, header=inferred_params_header(args.bag, lines))
    print("no --params: inferred from the recording")
    for line in lines:
        print(f"  {line}")
    print(f"  written to {out} (edit it and pass it with --params next time)")
    return params


def _run(args, warnings) -> int:
    from sclam_ros.core.config import CoreConfig
    from sclam_ros.core.estimator import calibrate_keyframes
    from sclam_ros.core.params import SclamParams, atomic_write_text
    from sclam_ros.cli.progress import ProgressBar
    from sclam_ros.io.recording import scan_frame_id
    from sclam_ros.io.tf_static import with_nominal_laser_pose
    from sclam_ros.io.truth import read_truth

    # Read first: a truth file that cannot be used fails before minutes of scan matching.
    truth = read_truth(args.truth) if args.truth else None
    if args.params is None:
        params = _inferred(args)
    else:
        params = SclamParams.from_yaml(args.params)
        # The URDF's laser pose (--urdf, or latched on /tf_static) for the laser_* the file leaves unset.
        params, laser_source = with_nominal_laser_pose(args.bag, params, args.urdf)
        print(laser_source)
    if args.track:
        return _run_track(args, params, truth)
    recording = _register(args, params, ProgressBar("reading + scan matching", not args.quiet))
    _explain_skid_steer(params, recording.wheel_sides)
    report = recording.report
    _warn_about_input(recording.rejections, report)
    if not args.quiet:
        log.info("solving the graph: %d scans", len(recording.keyframes))
    config = CoreConfig()
    result = calibrate_keyframes(
        recording.keyframes, params, recording.rejections,
        progress=(lambda i, cost: log.info("LM iteration %d, cost %.1f", i, cost))
        if args.verbose else None,
        config=config,
    )
    print(f"{result.scans_used} scans matched ({DecimationConfig().match_period:g} s apart) over {result.duration_s:.1f} s; "
          f"solver: {result.iterations} iterations, converged: {result.converged}")
    if not result.converged:
        log.warning("the solver stopped with the parameters still moving by more than %.2g σ "
                    "per step: the estimate is not final", config.estimator.converged_step_sigma)
    print(format_table(result, truth))
    _explain_unobserved(result.observable, report)
    _explain_dilution(result.wheel_noise_correction)
    if args.json:
        out = result.as_json()
        out["warnings"] = warnings
        out["messages"] = recording.messages
        out["frames"] = {"base": params.base_frame,
                         "laser": scan_frame_id(args.bag, params.scan_topic)}  # for sclam export
        if params.wheels_per_side > 1:  # a skid-steer's, for sclam export and the reader
            out["wheels_per_side"] = params.wheels_per_side
            out["wheel_separation"] = params.wheel_separation or None  # geometric
            out["wheel_sides"] = recording.wheel_sides
        atomic_write_text(args.json, json.dumps(out, indent=2) + "\n")
    if args.report:
        from sclam_ros.io.report import write_calibration_report

        figures = write_calibration_report(args.report, args.bag, result, params)
        print("figures: " + ", ".join(str(f) for f in figures))
    if args.trajectory:
        from sclam_ros.io.export import write_trajectories

        files = write_trajectories(args.trajectory, result, args.bag)
        print("trajectories (TUM): " + ", ".join(str(f) for f in files))
    return 0
