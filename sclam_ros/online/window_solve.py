"""A window solve as a job: prepared under the calibrator's lock, run on any thread.

The calibrator prepares a SolveJob (its problem and what applying the result needs),
run_solve does LM and the marginal covariance touching nothing but the job, and the
calibrator applies the SolveOutcome. Each solve first judges which directions of the
calibration the window and its priors determine (core/observability.py, at the warm start)
and locks the others at nominal.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np

from sclam_ros.core import graph as graph_mod
from sclam_ros.core.covariance import factorize_information, marginal_covariance
from sclam_ros.core.levenberg_marquardt import levenberg_marquardt
from sclam_ros.core.marginal import Gaussian
from sclam_ros.core.observability import Observability
from sclam_ros.online.config import WindowSolveConfig


@dataclass
class SolveJob:
    """A window problem to solve, and what it needs to be applied afterwards."""

    generation: int  # OnlineCalibrator.generation when it was prepared
    keyframe_indices: list
    stamp: float
    problem: object
    keyframes_in_window: int
    window_distance: float
    prior: Gaussian  # every prior of the problem, for the change test
    change_testable: bool  # enough marginalised radii information to test against
    nominal: np.ndarray  # (6,) where undetermined directions are locked
    reference: Gaussian  # the data older than the history (and the weak prior)
    history: list  # the history's Gaussians when the job was prepared, oldest first
    history_numbers: list  # their history.Chunk.number
    next_chunk_number: int  # of the first chunk marginalised after the job was prepared
    history_metres: list  # their metres, and the pose window's


@dataclass
class SolveOutcome:
    job: SolveJob
    calibration: np.ndarray
    covariance: np.ndarray  # under the stated noise model (the change test's)
    poses: np.ndarray
    converged: bool
    residual_rms: dict
    observability: Observability
    variance_factor: float = 1.0  # σ̂₀² of the window (window_variance_factor)


def run_solve(job: Optional[SolveJob], config: WindowSolveConfig) -> Optional[SolveOutcome]:
    """LM on a prepared window problem and the marginal covariance of the calibration."""
    from sclam_ros.core.estimator import residual_rms  # estimator imports nothing of the window

    if job is None:
        return None
    problem = job.problem
    # Judged at the warm start, before the lock is added (see Observability.of_problem).
    observability = Observability.of_problem(problem, graph_mod.prior_sigmas(job.nominal))
    problem.factors.extend(observability.lock(job.nominal))
    result = levenberg_marquardt(problem, max_iterations=config.max_iterations,
                                 relative_tolerance=config.relative_tolerance)
    calibration = graph_mod.calibration_of(result.values)
    if not np.all(np.isfinite(calibration)):
        return SolveOutcome(job, calibration, np.full((6, 6), np.nan), result.values["poses"],
                            False, {}, observability)
    system, _, factorized = factorize_information(problem, result.values, result.system)
    cov = marginal_covariance(problem, result.values, ["odometry", "laser"], lu=factorized)
    return SolveOutcome(job, calibration, cov, result.values["poses"], result.converged,
                        residual_rms(problem, result.values, result.system), observability,
                        window_variance_factor(system, problem.layout.size,
                                               config.variance_factor_limits))


def window_variance_factor(system, unknowns: int, limits) -> float:
    """The a-posteriori variance factor σ̂₀² = χ² / (rows − unknowns) of a window solve:
    by how much the stated noise model over- (< 1) or understates (> 1) the window's
    residuals, all factors together (the history's priors were made under the same model).
    The published covariance is the solve's times it (the change test keeps the stated
    model it is tuned on), `limits` (low, high) bound it."""
    redundancy = len(system.residual) - unknowns
    if redundancy <= 0:
        return 1.0
    return float(np.clip(np.sum(system.residual ** 2) / redundancy, *limits))
