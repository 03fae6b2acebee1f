"""The estimate's uncertainty from the information matrix H = JᵀJ of a Problem.

marginal_covariance is the block of H⁻¹ of the named variables; absorbed_trace and
redundancy_by_factor say how much of each factor group's χ² the variables absorb (the
redundancy variance components divide by); remaining_step is the Gauss-Newton step still
ahead; Influence holds J H⁻¹ E, how the whitened residuals move the named variables, which
the covariances that do not take every edge as independent (correlated_covariance) share.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np
import scipy.sparse as sp

from sclam_ros.core.linear import LinearSolver, _normal_equations
from sclam_ros.core.problem import Problem, System, Values


def factorize_information(problem: Problem, values: Values, system: Optional[System] = None):
    """Factorisation of the (robustly weighted) information matrix H = JᵀJ at `values`
    (`system`: the linear system at `values` if already at hand, e.g. SolverResult.system)."""
    if system is None:
        system = problem.linear_system(values)
    hessian, _ = _normal_equations(system)
    return system, hessian, LinearSolver(hessian, problem.banded_size, problem.linear)


def remaining_step(problem: Problem, values: Values, blocks):
    """The Gauss-Newton step Δ = −H⁻¹g still ahead at `values`, for the named blocks' free
    variables, and the factorisation of H (for marginal_covariance's `lu`). How far a
    continued solve would move the parameters, whatever stopped the iterations."""
    system, _, lu = factorize_information(problem, values)
    _, gradient = _normal_equations(system)
    cols = np.concatenate([problem.layout.columns(name) for name in blocks])
    return -lu.solve(gradient)[cols], lu


def marginal_covariance(problem: Problem, values: Values, blocks, lu=None):
    """Joint marginal covariance of the named blocks' free variables, (p, p).

    The marginal of a Gaussian is the corresponding block of H⁻¹: solve H X = E for the p
    unit columns E of those variables with one factorisation.
    """
    if lu is None:
        _, _, lu = factorize_information(problem, values)
    cols, solved = _inverse_columns(problem, blocks, lu)
    cov = solved[cols]
    return 0.5 * (cov + cov.T)


def _inverse_columns(problem: Problem, blocks, lu):
    """(columns of the named blocks' free variables, H⁻¹ E: those columns of H⁻¹), one
    solve with the factorisation `lu` for all of them."""
    cols = np.concatenate([problem.layout.columns(name) for name in blocks])
    unit = np.zeros((problem.layout.size, len(cols)))
    unit[cols, np.arange(len(cols))] = 1.0
    return cols, lu.solve(unit)


def absorbed_trace(rows, lu) -> float:
    """tr(J H⁻¹ Jᵀ) of whitened Jacobian rows J (sparse or dense), `lu` H's LinearSolver:
    the part of their expected χ² the variables absorb. Exact: Σ (JᵀJ)_ij (H⁻¹)_ij over
    JᵀJ's pattern, within H's (LinearSolver.inverse_at). Hutchinson's stochastic estimate
    is not used: on an outdoor drive the poses along a street are a long random walk of
    the odometry, H⁻¹ couples them all, and the probes' cross terms swamp the trace (even
    its sign)."""
    rows = rows if sp.issparse(rows) else sp.csr_matrix(np.asarray(rows))
    gram = (rows.T @ rows).tocoo()
    return float(gram.data @ lu.inverse_at(gram.row, gram.col))


def redundancy_by_factor(problem: Problem, values: Values):
    """Redundancy (observations minus the share of parameters each factor type determines).

    For variance component estimation: the expected χ² of factor group g at the optimum
    is r_g = n_g − tr(J_g H⁻¹ J_gᵀ) (absorbed_trace).
    """
    system, _, lu = factorize_information(problem, values)
    traces = {}
    for name, start, stop in system.row_ranges:
        traces[name] = traces.get(name, 0.0) + absorbed_trace(system.jacobian[start:stop], lu)
    out = {
        name: (stats["dim"] - traces[name], stats["chi2"])
        for name, stats in system.per_factor.items()
    }
    return out, lu


@dataclass
class Influence:
    """How the whitened residuals move the named blocks at `values` (for the covariances
    of correlated_covariance, which share it): the linear system there, the blocks'
    marginal H⁻¹ (p, p), and J H⁻¹ E (rows × p)."""

    system: System
    marginal: np.ndarray
    rows: np.ndarray
    lu: "LinearSolver"

    @classmethod
    def of(cls, problem: Problem, values: Values, blocks, lu=None) -> "Influence":
        system = problem.linear_system(values)
        if lu is None:
            hessian, _ = _normal_equations(system)
            lu = LinearSolver(hessian, problem.banded_size, problem.linear)
        cols, solved = _inverse_columns(problem, blocks, lu)
        marginal = solved[cols]
        return cls(system, 0.5 * (marginal + marginal.T), system.jacobian @ solved, lu)
