"""Calibrate the odometry against motion capture instead of scan matching.

A motion-capture marker is a pose sensor rigidly mounted on the robot at an unknown pose
m, exactly like the laser: its motion between two encoder-synced stamps,
z_ij = p_i⁻¹ ∘ p_j, enters the graph as a LaserFactor ((x_j ⊕ m) ⊖ (x_i ⊕ m)) ⊖ z_ij,
and m is estimated in the "laser" block (only its yaw and offset are defined by the
motion; the mocap world frame itself never enters, since only relative motions are used).

Keyframes are every ``step`` encoder samples (default 10 = 0.5 s at OptiOdom's 20 Hz).
Shorter steps were measured to fail on the circular runs (step 2 and 4: LM wanders to
r < 25 mm, unconverged): a 50 ms mocap motion is ~5 mm, comparable to mocap jitter and to
the one-cycle lag between the tick counts and the mocap sample, and at that rate the
odometry group lacks the redundancy for its variance component.  mocap and ticks share the stamps in the
OptiOdom run files, so no interpolation is needed.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np

from sclam_ros.core import graph as graph_mod
from sclam_ros.core import dilution, kinematics, se2
from sclam_ros.core.config import CoreConfig, MocapConfig
from sclam_ros.core.covariance import marginal_covariance
from sclam_ros.core.params import CALIBRATION_KEYS, SclamParams
from sclam_ros.core.variance_components import solve_with_variance_components


@dataclass
class MocapCalibration:
    estimate: np.ndarray  # (6,) r_l, r_r, b, marker x, y, yaw
    sigma: np.ndarray
    keyframes: int
    variance_scales: dict
    converged: bool
    wheel_noise_correction: Optional[dict] = None  # dilution.summary


def graph_inputs(stamps, ticks, truth, ticks_per_revolution, step=10,
                 config: MocapConfig = MocapConfig()) -> graph_mod.GraphInputs:
    keep = np.arange(0, len(stamps), step)
    angles = np.asarray(ticks, float)[keep] * 2 * np.pi / ticks_per_revolution
    poses = np.asarray(truth, float)[keep]
    n = len(keep)
    z = se2.between(poses[1:], poses[:-1])
    return graph_mod.GraphInputs(
        stamps=np.asarray(stamps, float)[keep],
        odo_from=np.arange(n - 1),
        odo_dphi=np.diff(angles, axis=0),
        laser_from=np.arange(n - 1),
        laser_to=np.arange(1, n),
        laser_z=z,
        laser_info=np.broadcast_to(np.diag(np.array(config.motion_sigma) ** -2.0),
                                   (n - 1, 3, 3)).copy(),
    )


def initial_mount_yaw(inputs: graph_mod.GraphInputs, k) -> float:
    """Yaw rotating the marker's translations onto the wheels' (closed form, as censi.py)."""
    odo = kinematics.forward(inputs.odo_dphi, k)
    a = odo[:, 0] + 1j * odo[:, 1]
    z = inputs.laser_z[:, 0] + 1j * inputs.laser_z[:, 1]
    return float(np.angle(np.sum(a * np.conj(z))))


def build_problem(inputs, params: SclamParams, k, fix_k=False,
                  config: CoreConfig = CoreConfig()):
    """The calibration graph of a run against its motion capture, started at k and the
    closed-form mount yaw; ``fix_k`` holds k there (only the mount and poses move)."""
    k = np.asarray(k, float)
    nominal = np.concatenate([k, [0.0, 0.0, initial_mount_yaw(inputs, k)]])
    problem = graph_mod.build_problem(
        inputs, params.with_calibration(dict(zip(CALIBRATION_KEYS, nominal))), nominal,
        config=config.graph, linear=config.linear)
    if fix_k:
        problem = type(problem)(problem.values, problem.factors,
                                fixed={**problem.fixed, "odometry": np.array([0])},
                                kernels=problem.kernels, scales=problem.scales,
                                corrections=problem.corrections, linear=problem.linear)
    return problem


def calibrate_with_ground_truth(stamps, ticks, truth, params: SclamParams, step=10,
                                fixed_k=None, config: CoreConfig = CoreConfig()):
    """k = (r_l, r_r, b) and the marker mount from the run; with ``fixed_k``, k is held
    there and only the mount (and the poses) are fitted: how another calibration is
    aligned with this run's motion capture (σ of the held k: 0)."""
    inputs = graph_inputs(stamps, ticks, truth, params.ticks_per_revolution, step, config.mocap)
    nominal_k = params.calibration_vector()[:3]
    held = fixed_k is not None
    problem = build_problem(inputs, params, fixed_k if held else nominal_k, fix_k=held,
                            config=config)
    result, scales = solve_with_variance_components(problem, config=config.solver)
    cov = marginal_covariance(problem, result.values, ["laser"] if held else ["odometry", "laser"])
    sigma = np.sqrt(np.diag(cov))
    return MocapCalibration(
        estimate=graph_mod.calibration_of(result.values),
        sigma=np.concatenate([np.zeros(3), sigma]) if held else sigma,
        keyframes=inputs.size,
        variance_scales=dict(scales),
        converged=result.converged,
        wheel_noise_correction=dilution.summary(
            problem, result.values, dict.fromkeys(CALIBRATION_KEYS[:3], not held)),
    )


# --- open-loop check: dead reckoning against motion capture -------------------------------


def dead_reckoning(ticks, k, ticks_per_revolution) -> np.ndarray:
    """Body poses (n, 3) from the wheel ticks alone, starting at the origin at cycle 0."""
    dphi = np.diff(np.asarray(ticks, float), axis=0) * 2 * np.pi / ticks_per_revolution
    return se2.chain(np.vstack([np.zeros(3), kinematics.forward(dphi, k)]))


def _ticks_at(ticks, lag):
    """Cumulative ticks read ``lag`` cycles later (fractional: linear interpolation)."""
    cycles = np.arange(len(ticks), dtype=float)
    return np.column_stack([np.interp(cycles + lag, cycles, ticks[:, c]) for c in range(2)])


def dead_reckoning_errors(ticks, truth, k, mount, ticks_per_revolution, window=100, stride=20,
                          lag=0.0):
    """Final error of dead reckoning over windows of ``window`` encoder cycles, started every
    ``stride`` cycles: translation (m) and |heading| (rad), each (windows,).

    Each window starts from the motion-capture pose, aligned through the marker mount m:
    the body is at p₀ ⊕ m⁻¹, wheel odometry with k carries it along, and its marker, x ⊕ m,
    is compared with the mocap pose at the window's end. The mount matters: a marker off the
    axle moves sideways in every turn, and a mount yaw turns every straight line. ``lag``
    pairs the mocap sample of cycle c with the ticks counted up to cycle c + lag (a lag > 0
    is an encoder clock ahead, the sign of the time_offset effect).
    """
    truth = np.asarray(truth, float)
    odometry = dead_reckoning(_ticks_at(np.asarray(ticks, float), lag), k, ticks_per_revolution)
    margin = int(np.ceil(abs(lag)))  # cycles the shifted ticks do not cover
    starts = np.arange(margin, len(truth) - window - margin, stride)
    ends = starts + window
    # The wheels' motion over a window, start to end, in the body frame at its start.
    motion = se2.between(odometry[ends], odometry[starts])
    body = se2.compose(truth[starts], se2.inverse(mount))
    predicted = se2.compose(se2.compose(body, motion), mount)
    error = predicted - truth[ends]
    return np.hypot(error[:, 0], error[:, 1]), np.abs(se2.wrap_angle(error[:, 2]))
