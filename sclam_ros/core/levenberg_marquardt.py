"""Levenberg-Marquardt on a Problem: the estimate.

Each iteration solves (H + λ·diag(H)) Δ = −g with LinearSolver and accepts the step when
the cost falls, adapting λ (Marquardt's diagonal damping). A candidate step is evaluated
by its whole linear system, which the next iteration then reuses.
"""
from __future__ import annotations

import math
import time

import numpy as np
import scipy.sparse as sp

from sclam_ros.core.config import SolverConfig
from sclam_ros.core.linear import LinearSolver, _normal_equations
from sclam_ros.core.problem import Problem, SolverResult


def _solve_damped(problem, hessian, gradient, damping):
    """Δ of (H + diag(damping)) Δ = −g, or None when the damped matrix is still not
    positive definite."""
    damped = hessian + (sp.diags(damping) if sp.issparse(hessian) else np.diag(damping))
    try:
        delta = LinearSolver(damped, problem.banded_size, problem.linear).solve(-gradient)
    except (np.linalg.LinAlgError, RuntimeError, ValueError):
        return None
    return delta if np.all(np.isfinite(delta)) else None


def _system_or_none(problem, values):
    """The linear system at `values`, or None where the model is not defined (a step so
    long that a noise model turns singular, e.g. a wheel base through zero): such a step
    is simply rejected. Evaluating a candidate step by its whole linear system, not its
    cost alone, costs a little more for a rejected step and saves the re-linearisation of
    every accepted one."""
    if not values.within_bounds():
        return None
    try:
        system = problem.linear_system(values)
    except (np.linalg.LinAlgError, FloatingPointError, ValueError):
        return None
    return system if math.isfinite(system.cost) else None


def _predicted_decrease(hessian, gradient, delta) -> float:
    """Cost decrease the linearised model promises for Δ: ‖r‖² − ‖r + JΔ‖²."""
    return float(-(2.0 * gradient @ delta + delta @ (hessian @ delta)))


def levenberg_marquardt(
    problem: Problem,
    max_iterations: int = SolverConfig.max_iterations,
    relative_tolerance: float = SolverConfig.relative_tolerance,
    initial_lambda: float = SolverConfig.initial_lambda,
    progress=None,
    min_lambda: float = SolverConfig.min_lambda,
) -> SolverResult:
    """Minimise Σ ρ(‖L e‖²) with Marquardt's diagonal damping and an adaptive λ; the
    defaults are SolverConfig's (SolverConfig.lm_options gives a config's)."""
    start = time.perf_counter()
    values = problem.values
    system = problem.linear_system(values)
    initial_cost = cost = system.cost
    lam, history, converged = initial_lambda, [cost], False
    iteration = 0
    for iteration in range(1, max_iterations + 1):
        hessian, gradient = _normal_equations(system)
        diag = np.maximum(hessian.diagonal(), 1e-9)

        def damped_step(lam):
            return _solve_damped(problem, hessian, gradient, lam * diag)

        accepted = False
        delta = damped_step(lam)
        # Even the model's own step gains less than the tolerance: at a minimum. Without
        # this stop a solve started at its optimum (a warm start) raises λ to 1e10 through
        # rejected steps, each a solve and a cost evaluation.
        at_minimum = delta is not None and (
            _predicted_decrease(hessian, gradient, delta) < relative_tolerance * cost)
        while not at_minimum and lam < 1e10:
            if delta is not None:
                candidate = values.retract(problem.layout, delta)
                candidate_system = _system_or_none(problem, candidate)
                if candidate_system is not None and candidate_system.cost < cost:
                    accepted = True
                    break
            lam *= 10.0
            delta = damped_step(lam) if lam < 1e10 else None
        if not accepted:
            converged = True  # at a minimum: no step gains enough, or none descends at all
            break
        new_cost = candidate_system.cost
        improvement = (cost - new_cost) / max(cost, 1e-300)
        values, system, cost = candidate, candidate_system, new_cost
        lam = max(lam / 10.0, min_lambda)
        history.append(cost)
        if progress is not None:
            progress(iteration, cost)
        if improvement < relative_tolerance:
            converged = True
            break
    return SolverResult(
        values, iteration, converged, initial_cost, cost, history, time.perf_counter() - start,
        system,
    )
