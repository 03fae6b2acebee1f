"""Maximum-likelihood factors on the wheels' noise, shared by the noise effects.

A noise effect changes the noise model, not the mean: it multiplies the wheel-noise part
of each edge's odometry covariance by a factor (disagreement.OdometryCovariance says why
that part). It is fitted to the laser-vs-odometry disagreements of a fit, whose covariance
is factor·(wheels' part) + (scan match and the odometry's other parts), through a function
nll(factors (m,)) -> per-edge negative log-likelihood (m,) (disagreement.Disagreement.nll).
Factors are searched within exp(±log_range) (NoiseConfig.log_range).
"""
from __future__ import annotations

import numpy as np
from scipy.optimize import minimize_scalar


def ml_factor(nll, inside, log_range: float) -> float:
    """The one factor on the wheels' noise of the `inside` edges minimising their NLL."""
    return float(np.exp(_best_log_factor(_region_nll(nll, inside), log_range)))


def ml_factor_with_sigma(nll, inside, log_range: float, step=0.05) -> tuple:
    """(factor, 1σ of its logarithm): the ML factor of ml_factor and the σ from the NLL's
    curvature in the log factor there (finite differences `step` apart; inf where the
    edges do not curve it, e.g. none inside)."""
    region_nll = _region_nll(nll, inside)
    best = _best_log_factor(region_nll, log_range)
    curvature = (region_nll(best + step) - 2.0 * region_nll(best) + region_nll(best - step)) / step**2
    sigma = 1.0 / np.sqrt(curvature) if curvature > 0 else np.inf
    return float(np.exp(best)), float(sigma)


def _region_nll(nll, inside):
    """log factor of the `inside` edges -> their summed NLL (the other edges at factor 1)."""
    def region_nll(log_factor):
        factors = np.ones(len(inside))
        factors[inside] = np.exp(log_factor)
        return float(np.sum(nll(factors)[inside]))
    return region_nll


def _best_log_factor(region_nll, log_range: float) -> float:
    return float(minimize_scalar(region_nll, bounds=(-log_range, log_range), method="bounded",
                                 options={"xatol": 1e-4}).x)


def nll_profile(nll, m, log_factors) -> np.ndarray:
    """(m, G) per-edge NLL at each of the G common factors exp(log_factors)."""
    return np.column_stack([nll(np.full(m, np.exp(g))) for g in log_factors])
