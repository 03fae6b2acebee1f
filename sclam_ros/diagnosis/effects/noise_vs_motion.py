"""Odometry noise that grows or shrinks with how the robot moves: speed, turn rate,
acceleration (wheels that skid more when fast, when turning hard, when accelerating).

log λ_e = b + a·z_e, z the edge's regressor standardised over the fitted edges, λ_e the
factor on its wheels' noise, fitted by maximum likelihood to the laser-vs-odometry
disagreements (see noise_fit) and divided by the one factor of all edges, so that the
effect models how the noise changes with the regressor, not the overall scale. The
stated noise already grows with the wheel angle turned (a random walk per radian); this
is what remains beyond it. Reported: the variance ratio between the regressor's 90th and
10th percentile over the recording. The slope is bounded (NoiseConfig.max_slope).
"""
from __future__ import annotations

import numpy as np
from scipy.optimize import minimize

from sclam_ros.diagnosis.config import DiagnoseConfig
from sclam_ros.diagnosis.effects.base import ModelEffect
from sclam_ros.diagnosis.effects.noise_fit import ml_factor


def pose_speeds(data) -> np.ndarray:
    """|v| (m/s) at each pose, from the fitted positions."""
    if len(data.stamps) < 3:
        return np.zeros(len(data.stamps))
    velocity = np.gradient(data.positions, data.stamps, axis=0)
    return np.hypot(velocity[:, 0], velocity[:, 1])


class NoiseVsMotion(ModelEffect):
    """Base: subclasses say which per-pose quantity the noise follows (`per_pose`)."""

    kind = "noise"
    dim = 1

    def __init__(self, data, config=DiagnoseConfig()):
        super().__init__(data, config)
        self.slope = 0.0
        self.mean, self.scale = 0.0, 1.0
        self.offset = 0.0  # log factor at z = 0, relative to all edges' factor
        self.spread = 0.0  # standardised 90th − 10th percentile

    def per_pose(self) -> np.ndarray:
        raise NotImplementedError

    def _regressor(self, pose_i, pose_j):
        x = self.per_pose()
        return 0.5 * (x[pose_i] + x[pose_j])

    def fit(self, pose_i, pose_j, nll):
        x = self._regressor(pose_i, pose_j)
        self.mean, self.scale = float(np.mean(x)), float(np.std(x)) or 1.0
        z = self._standardised(x)
        self.spread = float(np.ptp(np.percentile(z, [10, 90])))
        log_range = self.config.noise.log_range
        overall = np.log(ml_factor(nll, np.ones(len(z), bool), log_range))

        def total(p):
            # Within the factors ml_factor searches: a small wheel-noise share lets the
            # simplex wander to factors whose exp overflows.
            return float(np.sum(nll(np.exp(np.clip(p[1] + p[0] * z, -log_range, log_range)))))

        best = minimize(total, np.array([0.0, overall]), method="Nelder-Mead",
                        options={"xatol": 1e-4, "fatol": 1e-6})
        max_slope = self.config.noise.max_slope
        self.slope = float(np.clip(best.x[0], -max_slope, max_slope))
        # The level under the fitted slope, by the same bounded search as `overall`: the
        # simplex's intercept may wander where the clipped total is flat (every factor at
        # the bound: exact encoders) and would carry a change of the overall level (e^-0.23
        # there) that no slope asked for. With no slope the two searches are one: offset 0.
        slope_z = self.slope * z
        level = np.log(ml_factor(lambda factors: nll(factors * np.exp(slope_z)),
                                 np.ones(len(z), bool), log_range))
        self.offset = float(level - overall)

    def _standardised(self, x):
        # Clipped: one edge far outside the fitted range must not get an extreme factor.
        return np.clip((x - self.mean) / self.scale, -4.0, 4.0)

    def scale_of(self, pose_i, pose_j):
        return np.exp(self.offset + self.slope * self._standardised(self._regressor(pose_i, pose_j)))

    def value(self, p=None):
        return float(np.exp(self.slope * self.spread))


class NoiseVsSpeed(NoiseVsMotion):
    name = "noise_vs_speed"
    units = "variance ratio, 90th vs 10th percentile of |v|"
    doc = "odometry noise changing with the speed"

    def per_pose(self):
        return pose_speeds(self.data)


class NoiseVsTurnRate(NoiseVsMotion):
    name = "noise_vs_turn_rate"
    units = "variance ratio, 90th vs 10th percentile of |ω|"
    doc = "odometry noise changing with the turn rate"

    def per_pose(self):
        return np.abs(self.data.turn_rates)


class NoiseVsAcceleration(NoiseVsMotion):
    name = "noise_vs_acceleration"
    units = "variance ratio, 90th vs 10th percentile of |dv/dt|"
    doc = "odometry noise changing with the acceleration"

    def per_pose(self):
        if len(self.data.stamps) < 3:
            return np.zeros(len(self.data.stamps))
        return np.abs(np.gradient(pose_speeds(self.data), self.data.stamps))
