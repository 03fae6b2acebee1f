"""What the node reports about the online calibration, decided without ROS.

The node turns these into messages: the nine numbers of ``~/wheel_parameters`` and the
level, message and key/values of its ``/diagnostics`` status. Which parameters the data has
determined comes with the estimate (core/observability.py); an undetermined one is reported
at its nominal value. Kept free of rclpy so that every publishing decision is tested without
DDS.
"""
from __future__ import annotations

import math

from sclam_ros.core.params import CALIBRATION_KEYS, ODOMETRY_KEYS
from sclam_ros.online.change import change_weight
from sclam_ros.online.config import OnlineConfig

WHEEL_PARAMETER_COLUMNS = ODOMETRY_KEYS
WHEEL_PARAMETER_ROWS = ("value", "sigma", "observable")
OK, WARN = "OK", "WARN"


def wheel_parameters_data(estimate) -> list:
    """The 9 numbers of ``~/wheel_parameters``: values, σ, then observable (1 or 0) of
    (r_l, r_r, b). An unobserved value is the nominal one with its prior σ."""
    return ([float(estimate.values[k]) for k in WHEEL_PARAMETER_COLUMNS]
            + [float(estimate.sigma[k]) for k in WHEEL_PARAMETER_COLUMNS]
            + [float(estimate.observable[k]) for k in WHEEL_PARAMETER_COLUMNS])


def diagnostic_status(status, params, received, rejections, config: OnlineConfig):
    """(level, message, values) of the node's diagnostics from an estimate.CalibratorStatus
    of a calibrator tuned by `config`: level is OK or WARN, values an ordered {key: value}
    of what a person checks on a running calibration. A value that does not exist yet (no estimate, no change test) is absent,
    never "nan" or "n/a"."""
    cal = status
    estimate = cal.estimate
    values = {
        "window_keyframes": cal.window_keyframes,
        "window_length_m": f"{cal.window_length:.3f}",
        "window_distance_m": f"{cal.window_distance:.3f}",
        "window_fill_percent": f"{100.0 * cal.window_length / cal.window_distance:.1f}",
        "pose_window_length_m": f"{cal.pose_window_length:.3f}",
        "radius_changes_detected": cal.radius_changes,
        "solves": cal.solves,
        # the wheel input's messages: JointState, or the base's Odometry (odometry_topic)
        **{f"{name}_received": n for name, n in received.items() if name != "scan"},
        "scans_received": received["scan"],
        "scans_skipped_above_max_rate": cal.frontend.skipped_scans,
        "solves_unconverged_in_a_row": cal.unconverged_in_a_row,
        "scan_matches": cal.frontend.matches,
        "scan_matches_confirmed": cal.frontend.confirmed,
        "rejected_total": rejections.total(),
    }
    weight = math.nan  # the change model's weight in the published radii σ
    if math.isfinite(cal.change_statistic):
        weight = change_weight(cal.change_statistic, config.change.statistic)
        values["radius_change_chi2"] = f"{cal.change_statistic:.3g}"
        values["radius_change_weight"] = f"{weight:.2f}"
    level, message = WARN, "no estimate yet: drive the robot"
    if estimate is not None:
        values["last_solve_converged"] = str(bool(estimate.converged)).lower()
        if estimate.residual_rms:
            values["residual_rms"] = "; ".join(
                f"{name} " + " ".join(f"{v:.3g}" for v in rms)
                for name, rms in sorted(estimate.residual_rms.items())) + " (m, m, rad)"
        for key in CALIBRATION_KEYS:  # an unobserved value is the nominal one
            values[f"{key}"] = f"{estimate.values[key]:.6g}"
            values[f"{key}_sigma"] = f"{estimate.sigma[key]:.3g}"
            values[f"{key}_observable"] = str(cal.observable[key]).lower()
        missing = [k for k in CALIBRATION_KEYS if not cal.observable[k]]
        if missing:
            message = "not observed by the data yet, kept at nominal: " + ", ".join(missing)
        elif weight > config.status.change_suspected:
            # The radii published are those before a change the test is about to declare;
            # their σ is widened to cover it (change.radii_covariance_with_change).
            message = ("the wheel radii may have changed (a load put on or taken off?): their "
                       "σ is widened until the change test decides")
        elif cal.unconverged_in_a_row >= config.status.unconverged_warning:
            # One capped solve is normal (the next, warm-started, carries on); a run
            # of them means the window's optimum keeps moving away.
            message = f"{cal.unconverged_in_a_row} solves in a row did not converge"
        else:
            level, message = OK, "calibrated"
        if cal.frontend.sigma_may_be_small:
            level = WARN
            message += ("; the σ may be too small: a noisy laser with most scan matches "
                        "unconfirmed (few straight surfaces in view; docs/accuracy.md)")
    for reason, n in sorted(rejections.counts.items()):
        values[f"rejected_{reason}"] = n
    return level, message, values
