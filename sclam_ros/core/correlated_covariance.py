"""Covariances of the estimate that do not take every edge as independent.

H⁻¹ is right only if every edge's noise is independent with its stated covariance.
Consecutive scan matches share a scan, so their errors correlate; chain_correlated_covariance
puts that correlation (and each odometry component's own noise scale) into H⁻¹ Jᵀ C J H⁻¹,
sandwich_covariance measures the spread from the residuals themselves.
"""
from __future__ import annotations

from typing import Optional

import numpy as np

from sclam_ros.core.config import SolverConfig
from sclam_ros.core.covariance import Influence
from sclam_ros.core.problem import Problem, Values
from sclam_ros.core.variance_components import component_scales


def chained_edges(factor):
    """Index pairs (t, u) of a factor's edges where edge u starts at the pose edge t ends at."""
    start = {int(i): n for n, i in enumerate(factor.pose_i)}
    t = np.array([n for n, j in enumerate(factor.pose_j) if int(j) in start], int)
    u = np.array([start[int(factor.pose_j[n])] for n in t], int)
    return t, u


def lag1_correlation(whitened, t, u) -> np.ndarray:
    """Pooled lag-1 correlation per component of whitened residuals (m, d) over pairs (t, u)."""
    if len(t) == 0:
        return np.zeros(whitened.shape[1])
    cross = np.mean(whitened[t] * whitened[u], axis=0)
    return cross / np.maximum(np.mean(whitened**2, axis=0), 1e-300)


def chain_correlated_covariance(problem: Problem, values: Values, blocks, lu=None,
                                influence: Optional[Influence] = None, per_component=True,
                                config: SolverConfig = SolverConfig()):
    """H⁻¹ (Jᵀ C J) H⁻¹ of the named blocks, with C the errors' covariance when consecutive
    edges of a factor with `chained_errors` are correlated; and those correlations.

    H⁻¹ assumes every edge independent. Consecutive scan matches share a scan, whose own
    registration error enters them with opposite signs, so their errors correlate negatively
    and cancel where a parameter averages over many edges (the laser pose): H⁻¹ overstates
    its σ. In whitened units C has the identity on its diagonal and diag(ρ) between chained
    edges, ρ per component pooled over the recording from the residuals, one number each, so
    it is not noisy as the sandwich's per-edge products are. The residuals' correlation
    understates the errors' (the poses absorb part of each; docs/decisions/error_structure.md
    records the errors' own at the simulator's truth), so the correction errs toward H⁻¹.
    Only cancellation is taken from it (ρ clipped to [−0.5, 0]: −0.5 is a scan's error
    alone, and C stays positive semidefinite); a positive correlation is the sandwich's to
    report. The other measurement edges (the odometry) enter with their noise scale per
    component (component_scales) where `per_component`: in the sandwich H⁻¹ Jᵀ C J H⁻¹ their
    block of C is diag(scales), so that a part of the stated model too large for these data
    (the sideways slip) does not widen the σ of what rests on it, while the estimate keeps
    the variance components' weights. `influence`: Influence.of(problem, values, blocks, lu)
    if already at hand; `config`: component_scales' redundancy threshold.
    """
    influence = influence or Influence.of(problem, values, blocks, lu)
    system, cov = influence.system, influence.marginal
    correlations = {}
    factor_rows = iter(system.row_ranges)
    for factor in problem.factors:
        if len(factor) == 0:
            continue
        name, start, stop = next(factor_rows)
        d = factor.edge_dim
        if per_component and factor.measurement and not getattr(factor, "chained_errors", False):
            scales = component_scales(influence, start, stop, d, config)
            rows = influence.rows[start:stop].reshape(-1, d, influence.rows.shape[1])
            cov = cov + np.einsum("tip,i,tiq->pq", rows, scales - 1.0, rows)
            continue
        if not getattr(factor, "chained_errors", False):
            continue
        t, u = chained_edges(factor)
        rho = np.clip(lag1_correlation(system.residual[start:stop].reshape(-1, d), t, u), -0.5, 0.0)
        correlations[name] = rho
        rows = influence.rows[start:stop].reshape(-1, d, influence.rows.shape[1])
        cross = np.einsum("tip,i,tiq->pq", rows[t], rho, rows[u])
        cov = cov + cross + cross.T
    return 0.5 * (cov + cov.T), correlations


def sandwich_covariance(problem: Problem, values: Values, blocks, lags: int = 1, lu=None,
                        influence: Optional[Influence] = None):
    """Heteroscedasticity- and autocorrelation-consistent covariance of the named blocks.

    The model covariance H⁻¹ is right only if every edge's noise is independent with the
    stated covariance. Scan matches are not: consecutive matches share a scan, so their
    errors are correlated (negatively, at lag 1), and H⁻¹ overstates the uncertainty of what
    averages over many edges. The sandwich estimator H⁻¹ (Σ_t Σ_t' s_t s_t'ᵀ) H⁻¹, with s_t
    the summed scores J_eᵀ r_e of the measurement edges ending at pose t, over pairs up to
    `lags` apart, measures the spread from the residuals themselves. Pairwise scan matching
    makes the errors MA(1) (correlated at lag 1, not measurably beyond), for which the
    truncated (uniform) kernel at lag 1 is exact, where Newey-West's Bartlett weights would
    keep a third of the variance that cancels. The truncated estimate need not be positive
    semidefinite: negative eigenvalues are clipped to zero. `influence`:
    Influence.of(problem, values, blocks, lu) if already at hand.
    """
    influence = influence or Influence.of(problem, values, blocks, lu)
    system = influence.system
    cols = influence.rows.shape[1]
    # Scores of all measurement edges that end at the same pose are one time step's
    # contribution: the odometry and the laser edge of an interval are fitted to the same
    # pose difference, so their residuals are correlated and must be summed, not counted
    # as independent.
    n_time = max((int(f.pose_j.max()) + 1 for f in problem.factors
                  if f.measurement and len(f) and hasattr(f, "pose_j")), default=0)
    per_time = np.zeros((n_time, cols))
    meat = np.zeros((cols, cols))
    factor_rows = iter(system.row_ranges)
    for factor in problem.factors:
        if len(factor) == 0:
            continue
        name, start, stop = next(factor_rows)
        if not factor.measurement:
            continue
        d = factor.edge_dim
        scores = (influence.rows[start:stop] * system.residual[start:stop, None]).reshape(-1, d, cols).sum(1)
        if hasattr(factor, "pose_j"):
            np.add.at(per_time, factor.pose_j, scores)
        else:  # no time order known: independent edges
            meat += scores.T @ scores
    meat += per_time.T @ per_time
    for lag in range(1, lags + 1):
        cross = per_time[:-lag].T @ per_time[lag:]
        meat += cross + cross.T
    meat = 0.5 * (meat + meat.T)
    eigval, eigvec = np.linalg.eigh(meat)
    meat = (eigvec * np.clip(eigval, 0.0, None)) @ eigvec.T
    return 0.5 * (meat + meat.T)
