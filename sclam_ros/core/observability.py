"""Which calibration parameters the data determines, from the information it carries.

One decision for the batch calibrator and the online window alike:

    Σ   joint marginal covariance of the six parameters (the inverse of their information,
        the Schur complement of the whole graph's information onto them), from a problem
        whose only pull on them is data and the weak prior of graph.prior_sigmas;
    C = S⁻¹ Σ S⁻¹ with S = diag(prior σ): whitened so that metres, radians, radii and base
        compare. The prior alone gives C = I; with the data's information A (whitened),
        C = (I + A)⁻¹, so an eigenvalue λ of C is 1 / (1 + g) with g the information the
        data adds along that eigen-direction, in units of the prior's.

A direction with g < min_information_gain (ObservabilityConfig) is undetermined: the data says
less about it than it would take to shrink the prior σ tenfold (or less than
min_information_gain_per_edge per edge, a level the noise of the estimated poses alone reaches
on a long run). It is locked at the nominal (or previously saved) value; the determined
directions stay free, so where only a combination is missing (spinning in place fixes the
radii relative to the base, not their common scale) only that combination is held. A
parameter is flagged unobservable when locking moves it: when the undetermined directions, at
their prior σ, leave it at least unobserved_sigma_ratio of its own prior σ (the
same tenfold: a parameter shares the threshold of the directions it is made of).

Why the covariance and not the information: C's eigenvalues near 1 (the undetermined ones)
are the large ones, which an eigen-decomposition gets to full relative precision however
well the others are determined; Λ = Σ⁻¹ would put them at the noise floor of the best
determined direction (the laser yaw, ~10⁸ × its prior's information on a long run).

Why the thresholds are where they are: docs/decisions/observability.md.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sclam_ros.core.config import ObservabilityConfig
from sclam_ros.core.covariance import marginal_covariance
from sclam_ros.core.levenberg_marquardt import levenberg_marquardt
from sclam_ros.core.marginal import CalibrationPriorFactor, Gaussian
from sclam_ros.core.params import CALIBRATION_KEYS
from sclam_ros.core.problem import Problem


@dataclass(frozen=True)
class Observability:
    prior_sigma: np.ndarray  # (6,) S
    gains: np.ndarray  # (6,) information added by the data per eigen-direction, ascending
    directions: np.ndarray  # (6, 6) columns: the eigen-directions of C, whitened
    observable: np.ndarray  # (6,) bool per CALIBRATION_KEYS
    threshold: float  # the gain a determined direction has at least
    config: ObservabilityConfig = ObservabilityConfig()  # the thresholds judged by, the lock's σ

    @classmethod
    def from_covariance(cls, covariance, prior_sigma, edges: int = 0,
                        config: ObservabilityConfig = ObservabilityConfig()) -> "Observability":
        """`edges`: measured edges the covariance comes from
        (config.min_information_gain_per_edge)."""
        threshold = max(config.min_information_gain, config.min_information_gain_per_edge * edges)
        prior_sigma = np.asarray(prior_sigma, float)
        whitened = np.asarray(covariance, float) / np.outer(prior_sigma, prior_sigma)
        values, vectors = np.linalg.eigh(0.5 * (whitened + whitened.T))
        gains = 1.0 / np.maximum(values, 1e-300) - 1.0
        order = np.argsort(gains)
        gains, vectors = gains[order], vectors[:, order]
        missing = vectors[:, gains < threshold]
        unresolved = np.sqrt(np.sum(missing**2, axis=1))  # in units of the prior σ
        return cls(prior_sigma, gains, vectors, unresolved < config.unobserved_sigma_ratio,
                   threshold, config)

    @classmethod
    def of_problem(cls, problem, prior_sigma, values=None,
                   config: ObservabilityConfig = ObservabilityConfig()) -> "Observability":
        """Judged on a problem's graph at `values` (default: its current values). The problem
        must hold no lock: a lock is information the data did not give."""
        values = problem.values if values is None else values
        edges = sum(len(f) for f in problem.factors if f.measurement)
        return cls.from_covariance(
            marginal_covariance(problem, values, ["odometry", "laser"]), prior_sigma, edges, config)

    @classmethod
    def of_settled_problem(cls, problem, prior_sigma,
                           config: ObservabilityConfig = ObservabilityConfig()) -> "Observability":
        """Judged with the poses first settled at the calibration as it is (see settle_poses);
        the problem's values become the settled ones, a better start for its own solve."""
        problem.values = settle_poses(problem, config)
        return cls.of_problem(problem, prior_sigma, config=config)

    @property
    def undetermined(self) -> np.ndarray:
        """(6, d) orthonormal undetermined directions, in prior-whitened coordinates."""
        return self.directions[:, self.gains < self.threshold]

    def as_dict(self) -> dict:
        return {k: bool(o) for k, o in zip(CALIBRATION_KEYS, self.observable)}

    def lock(self, values) -> list:
        """Factors holding the undetermined directions at `values` (nominal or saved); none
        when everything is determined. The determined directions feel no pull."""
        missing = self.undetermined
        if missing.shape[1] == 0:
            return []
        unwhiten = 1.0 / self.prior_sigma
        information = (self.config.lock_sigma_ratio**-2.0) * (
            unwhiten[:, None] * (missing @ missing.T) * unwhiten[None, :])
        values = np.asarray(values, float)
        factor = CalibrationPriorFactor(Gaussian(information, information @ values), mean=values)
        factor.name = "locked_calibration"
        return [factor]

    def reported(self, estimate, locked_values) -> np.ndarray:
        """What may be published: flagged parameters at their locked (nominal/saved) value."""
        return np.where(self.observable, np.asarray(estimate, float), np.asarray(locked_values, float))

    def reported_covariance(self, covariance) -> np.ndarray:
        """`covariance` of a locked solve with the locked directions given back their prior
        variance (the lock knows nothing); flagged parameters then get their prior σ and no
        correlations: "unknown", not a σ the lock made up."""
        missing = self.prior_sigma[:, None] * self.undetermined
        cov = np.array(covariance, float) + missing @ missing.T
        flagged = ~self.observable
        cov[flagged, :] = 0.0
        cov[:, flagged] = 0.0
        cov[flagged, flagged] = self.prior_sigma[flagged] ** 2
        return cov


def settle_poses(problem, config: ObservabilityConfig = ObservabilityConfig()):
    """The problem's values with the poses at their optimum for the calibration held as it is.

    The information about a direction the motion does not excite is zero only at poses that
    show no motion the robot did not make. Poses chained from the scan matches carry their
    noise: standing still, their small jitter looks like motion whose laser Jacobians
    inform the laser yaw; spinning in place, the laser offset rotated with its yaw. That
    spurious information grows with every edge. Settled on the wheels too, which see the
    robot stand or spin more precisely, the poses lose most of it (measured:
    docs/decisions/observability.md). At most config.settle_iterations LM iterations, to
    config.settle_tolerance.
    """
    held = dict(problem.fixed)
    held["odometry"] = np.arange(len(problem.values["odometry"]))
    held["laser"] = np.arange(len(problem.values["laser"]))
    poses_only = Problem(problem.values, problem.factors, fixed=held, kernels=problem.kernels,
                         scales=problem.scales, linear=problem.linear)
    return levenberg_marquardt(poses_only, max_iterations=config.settle_iterations,
                               relative_tolerance=config.settle_tolerance).values
