"""Gaussians on the calibration left behind by marginalised keyframes, and what the
online window does with them: a prior factor, and a test for a change of the radii.

All of them are over the six CALIBRATION_KEYS (r_l, r_r, b, l_x, l_y, l_yaw) in
information form (Λ, η = Λ μ): information from independent chunks of data adds, and a
parameter nothing has informed yet simply has zero rows.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from sclam_ros.core import factors

RADII = [0, 1]
NOT_RADII = [2, 3, 4, 5]


@dataclass
class Gaussian:
    information: np.ndarray = field(default_factory=lambda: np.zeros((6, 6)))
    eta: np.ndarray = field(default_factory=lambda: np.zeros(6))

    def __add__(self, other: "Gaussian") -> "Gaussian":
        return Gaussian(self.information + other.information, self.eta + other.eta)

    def is_empty(self) -> bool:
        return not np.any(self.information)

    def mean(self) -> np.ndarray:
        """A mean (the minimum-norm one where some direction has no information)."""
        return np.linalg.lstsq(self.information, self.eta, rcond=1e-12)[0]

    def without_radii(self) -> "Gaussian":
        """The radii integrated out (a Schur complement of Λ and η): what this data says
        about (b, l) whatever the radii were while it was driven."""
        info, eta = self.information, self.eta
        l_rr_pinv = np.linalg.pinv(info[np.ix_(RADII, RADII)], hermitian=True)
        l_sr = info[np.ix_(NOT_RADII, RADII)]
        out = Gaussian()
        out.information[np.ix_(NOT_RADII, NOT_RADII)] = (
            info[np.ix_(NOT_RADII, NOT_RADII)] - l_sr @ l_rr_pinv @ l_sr.T)
        out.eta[NOT_RADII] = eta[NOT_RADII] - l_sr @ l_rr_pinv @ eta[RADII]
        return out


def gaussian_of_prior(mean, sigma) -> Gaussian:
    information = np.diag(np.asarray(sigma, float) ** -2.0)
    return Gaussian(information, information @ np.asarray(mean, float))


class CalibrationPriorFactor(factors.Factor):
    """A Gaussian on the calibration as a factor over the odometry and laser blocks."""

    name = "marginal_prior"
    measurement = False

    def __init__(self, gaussian: Gaussian, mean=None):
        """`mean`: a point with information η = Λ mean, where Λ is singular and one is known
        (a lock at given values): the minimum-norm mean can lie far off along the free
        directions, and the residual's large components then cancel in Λ^½ r."""
        self.mean = gaussian.mean() if mean is None else np.asarray(mean, float)
        # Λ may be singular (the radii after a change): a square root from its
        # eigen-decomposition weighs exactly the directions that have information.
        values, vectors = np.linalg.eigh(0.5 * (gaussian.information + gaussian.information.T))
        self._sqrt_info = (np.sqrt(np.clip(values, 0.0, None))[:, None] * vectors.T)[None]

    def __len__(self):
        return 1

    def linearize(self, values):
        current = np.concatenate([values["odometry"][0], values["laser"][0]])
        residual = current - self.mean
        residual[5] = (residual[5] + np.pi) % (2 * np.pi) - np.pi
        j_odo = np.zeros((1, 6, 3))
        j_odo[0, :3, :] = np.eye(3)
        j_laser = np.zeros((1, 6, 3))
        j_laser[0, 3:, :] = np.eye(3)
        zeros = np.zeros(1, int)
        return factors.Linearization(
            residual[None], self._sqrt_info,
            [factors.JacobianBlock("odometry", zeros, j_odo),
             factors.JacobianBlock("laser", zeros, j_laser)],
        )
