"""What the node reports about the online calibration, decided without ROS.

The node turns these into messages: the six numbers of ``~/wheel_parameters``, which
parameters the data has determined, and the level, message and key/values of its
``/diagnostics`` status. Kept free of rclpy so that every publishing decision is tested
without DDS.
"""
from __future__ import annotations

import numpy as np

from sclam_ros.core import graph as graph_mod
from sclam_ros.core.params import CALIBRATION_KEYS, ODOMETRY_KEYS

WHEEL_PARAMETER_COLUMNS = ODOMETRY_KEYS
WHEEL_PARAMETER_ROWS = ("value", "sigma")
UNCONVERGED_WARNING = 3  # window solves in a row that hit their iteration cap
OK, WARN = "OK", "WARN"


def wheel_parameters_data(values, sigma) -> list:
    """The 6 numbers of ``~/wheel_parameters``: values then σ of (r_l, r_r, b)."""
    return [float(values[k]) for k in WHEEL_PARAMETER_COLUMNS] + [
        float(sigma[k]) for k in WHEEL_PARAMETER_COLUMNS
    ]


def observability(estimate, nominal) -> dict:
    """key → σ < ½ of its prior σ (the data, not the prior, determines it)."""
    prior = graph_mod.prior_sigmas(np.asarray(nominal, float))
    return {k: bool(estimate.sigma[k] < 0.5 * prior[i]) for i, k in enumerate(CALIBRATION_KEYS)}


def diagnostic_status(status, params, received, rejections):
    """(level, message, values) of the node's diagnostics from a window.CalibratorStatus:
    level is OK or WARN, values an ordered {key: value} of what a person checks on a running
    calibration."""
    cal = status
    estimate = cal.estimate
    values = {
        "window_keyframes": cal.window_keyframes,
        "window_length_m": f"{cal.window_length:.3f}",
        "window_distance_m": f"{cal.window_distance:.3f}",
        "window_fill_percent": f"{100.0 * cal.window_length / cal.window_distance:.1f}",
        "pose_window_length_m": f"{cal.pose_window_length:.3f}",
        "radius_changes_detected": cal.radius_changes,
        "radius_change_chi2": f"{cal.change_statistic:.3g}",
        "solves": cal.solves,
        "joint_states_received": received["joint_states"],
        "scans_received": received["scan"],
        "scans_skipped_above_max_rate": cal.skipped_scans,
        "last_solve_converged": "n/a" if estimate is None else str(bool(estimate.converged)).lower(),
        "solves_unconverged_in_a_row": cal.unconverged_in_a_row,
        "residual_rms": "n/a" if estimate is None or not estimate.residual_rms else "; ".join(
            f"{name} " + " ".join(f"{v:.3g}" for v in rms)
            for name, rms in sorted(estimate.residual_rms.items())) + " (m, m, rad)",
        "rejected_total": rejections.total(),
    }
    level, message = WARN, "no estimate yet: drive the robot"
    if estimate is not None:
        observable = observability(estimate, cal.nominal)
        for key in CALIBRATION_KEYS:
            values[f"{key}"] = f"{estimate.values[key]:.6g}"
            values[f"{key}_sigma"] = f"{estimate.sigma[key]:.3g}"
            values[f"{key}_observable"] = str(observable[key]).lower()
        missing = [k for k, ok in observable.items() if not ok]
        if missing:
            message = "not yet observable: " + ", ".join(missing)
        elif cal.unconverged_in_a_row >= UNCONVERGED_WARNING:
            # One capped solve is normal (the next, warm-started, carries on); a run
            # of them means the window's optimum keeps moving away.
            message = f"{cal.unconverged_in_a_row} solves in a row did not converge"
        else:
            level, message = OK, "calibrated"
    for reason, n in sorted(rejections.counts.items()):
        values[f"rejected_{reason}"] = n
    return level, message, values
