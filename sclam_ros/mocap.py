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

import numpy as np

from . import graph as graph_mod
from . import kinematics, se2
from .params import CALIBRATION_KEYS, SclamParams
from .solver import marginal_covariance, solve_with_variance_components

# Noise shape of one mocap relative motion (scale estimated by variance components).
MOCAP_SIGMA = np.array([0.001, 0.001, 0.005])  # m, m, rad


@dataclass
class MocapCalibration:
    estimate: np.ndarray  # (6,) r_l, r_r, b, marker x, y, yaw
    sigma: np.ndarray
    keyframes: int
    variance_scales: dict
    converged: bool


def graph_inputs(stamps, ticks, truth, ticks_per_revolution, step=10) -> graph_mod.GraphInputs:
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
        laser_info=np.broadcast_to(np.diag(MOCAP_SIGMA**-2.0), (n - 1, 3, 3)).copy(),
    )


def initial_mount_yaw(inputs: graph_mod.GraphInputs, k) -> float:
    """Yaw rotating the marker's translations onto the wheels' (closed form, as censi.py)."""
    odo = kinematics.forward(inputs.odo_dphi, k)
    a = odo[:, 0] + 1j * odo[:, 1]
    z = inputs.laser_z[:, 0] + 1j * inputs.laser_z[:, 1]
    return float(np.angle(np.sum(a * np.conj(z))))


def calibrate_with_ground_truth(stamps, ticks, truth, params: SclamParams, step=10):
    inputs = graph_inputs(stamps, ticks, truth, params.ticks_per_revolution, step)
    k = np.array([params.wheel_radius_left, params.wheel_radius_right, params.wheel_base])
    nominal = np.concatenate([k, [0.0, 0.0, initial_mount_yaw(inputs, k)]])
    problem = graph_mod.build_problem(
        inputs, params.with_calibration(dict(zip(CALIBRATION_KEYS, nominal))), nominal)
    result, scales = solve_with_variance_components(problem)
    cov = marginal_covariance(problem, result.values, ["odometry", "laser"])
    return MocapCalibration(
        estimate=graph_mod.calibration_of(result.values),
        sigma=np.sqrt(np.diag(cov)),
        keyframes=inputs.size,
        variance_scales=dict(scales),
        converged=result.converged,
    )
