"""Batch calibration: all keyframes of a recording in one graph, solved jointly.

    keyframes → graph (poses, k, l) → LM with variance components → estimate, marginal σ
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional

import numpy as np

from sclam_ros.core import dilution
from sclam_ros.core import graph as graph_mod
from sclam_ros.core.config import CoreConfig, WiringConfig
from sclam_ros.core.correlated_covariance import chain_correlated_covariance, sandwich_covariance
from sclam_ros.core.covariance import Influence, remaining_step
from sclam_ros.core.inputs import Rejections
from sclam_ros.core.observability import Observability
from sclam_ros.core.params import CALIBRATION_KEYS
from sclam_ros.core.variance_components import solve_with_variance_components
from sclam_ros.core.wiring import wiring_problem

class CalibrationError(RuntimeError):
    """The data cannot support a calibration; the message says why and what to do."""


@dataclass
class CalibrationResult:
    estimate: dict  # the six parameters (m, rad)
    sigma: dict  # their marginal 1σ
    # (6, 6) reported: see _at_least and correlated_covariance.chain_correlated_covariance
    covariance: np.ndarray
    model_covariance: np.ndarray  # (6, 6) H⁻¹ marginal under the noise model
    nominal: dict
    observable: dict  # name -> bool
    scans_used: int
    duration_s: float
    residual_rms: dict  # edge type -> (3,) RMS of the raw residual components (m, m, rad)
    variance_scales: dict  # edge type -> estimated variance factor of its noise model
    iterations: int
    converged: bool
    stamps: np.ndarray = field(repr=False, default=None)
    poses: np.ndarray = field(repr=False, default=None)  # optimised, (n, 3)
    inputs: object = field(repr=False, default=None)  # graph.GraphInputs
    problem: object = field(repr=False, default=None)
    rejections: Rejections = field(default_factory=Rejections)
    observability: Observability = field(repr=False, default=None)  # what `observable` comes from
    # The wheel noise's dilution of k (dilution.py): whether the correction was applied and
    # how far it moved (or would have moved) r_l, r_r, b, in per cent; None: no correction
    wheel_noise_correction: Optional[dict] = None

    def as_json(self) -> dict:
        out = {k: self.estimate[k] for k in CALIBRATION_KEYS}
        out["sigma"] = {k: self.sigma[k] for k in CALIBRATION_KEYS}
        out["scans_used"] = int(self.scans_used)
        out["duration_s"] = float(self.duration_s)
        out["converged"] = bool(self.converged)
        out["observable"] = {k: bool(self.observable[k]) for k in CALIBRATION_KEYS}
        # What an unobservable parameter stays at in exports (sclam export) without the
        # parameters file it came from.
        out["nominal"] = {k: float(self.nominal[k]) for k in CALIBRATION_KEYS}
        out["rejected"] = dict(sorted(self.rejections.counts.items()))
        if self.wheel_noise_correction is not None:
            out["wheel_noise_correction"] = self.wheel_noise_correction
        return out


def _at_least(model, sandwich):
    """The model covariance, scaled up per parameter where the sandwich σ is larger.

    The noise model's covariance (H⁻¹ with consecutive scan matches' measured correlation,
    correlated_covariance.chain_correlated_covariance) is right when the edges' noise is as
    stated; the sandwich σ measures the spread from the residuals (heteroscedasticity, correlated
    scan-match errors, a misfit noise shape) but is itself noisy on short runs. Neither may
    claim more certainty than the other supports (docs/decisions/uncertainty.md#either-way).
    Row/column scaling D·Σ·D keeps the covariance positive semidefinite.
    """
    ratio = np.sqrt(np.diag(sandwich)) / np.maximum(np.sqrt(np.diag(model)), 1e-300)
    scale = np.maximum(1.0, ratio)
    return model * np.outer(scale, scale)


def residual_rms(problem, values, system=None) -> dict:
    """RMS of the raw residuals per measurement factor type and component; `system`: the
    linear system at `values` if at hand (e.g. SolverResult.system), saving a linearisation."""
    if system is None:
        system = problem.linear_system(values)
    measured = {f.name for f in problem.factors if f.measurement}
    return {name: np.sqrt(stats["squared_residual_sum"] / stats["count"])
            for name, stats in system.per_factor.items() if name in measured}


def check_wiring(keyframes, params, config: WiringConfig = WiringConfig()) -> None:
    """CalibrationError naming the fix if the encoders contradict the laser's motion
    (core/wiring.py): swapped or backwards encoders make every number the graph would
    give wrong. The batch solve and `sclam calibrate --track` both refuse on it."""
    miswired = wiring_problem(keyframes, params, config)
    if miswired:
        raise CalibrationError(miswired)


def _judged_again(problem, observability, locks, result, scales, nominal, prior_sigma,
                  progress, config: CoreConfig):
    """Observability judged again at the locked solution; where that determines a direction
    the start did not, the lock is lifted from it and the problem solved again.

    The start is a poor place to judge when a nominal value is far off: a laser mounted at
    (0.3 m, 0.6 m, 30°) judged at (0, 0, 0) left the radii and base's common scale with a
    gain of 252 against a threshold of 1011 on a 300 s route (the route determines it). At
    the locked solution the laser pose is fitted and the locked direction still sits at
    nominal (the lock held it), so it cannot have wandered to where the curvature looks
    informative; a direction the motion does not excite (a spin, a straight line) stays
    undetermined there too (the same thresholds)."""
    problem.factors = [f for f in problem.factors if f not in locks]
    again = Observability.of_problem(problem, prior_sigma, values=result.values,
                                     config=config.observability)
    if np.sum(again.observable) <= np.sum(observability.observable):
        problem.factors.extend(locks)
        return observability, result, scales
    problem.values = result.values
    problem.factors.extend(again.lock(nominal))
    result, scales = solve_with_variance_components(problem, progress=progress,
                                                    config=config.solver)
    return again, result, scales


def calibrate_keyframes(keyframes, params, rejections=None, progress=None,
                        correct_dilution=True,
                        config: CoreConfig = CoreConfig()) -> CalibrationResult:
    """The batch calibration of a recording's keyframes; correct_dilution: take the wheel
    noise's regression dilution out of k (core/dilution.py); `config`: the developer
    tuning, each section handed to the function it tunes."""
    if len(keyframes) < config.estimator.min_keyframes:
        raise CalibrationError(
            f"only {len(keyframes)} scans could be paired with encoder data (need at least "
            f"{config.estimator.min_keyframes}); check the topic names, joint names and that "
            f"the clocks of both sensors overlap. Rejections: {rejections or 'none'}"
        )
    check_wiring(keyframes, params, config.wiring)
    inputs = graph_mod.GraphInputs.from_keyframes(
        graph_mod.merge_keyframes(keyframes, params.keyframe_interval, config.graph))
    if len(inputs.odo_from) == 0 or len(inputs.laser_from) == 0:
        unconfirmed = rejections is not None and rejections.counts.get("match_unconfirmed", 0)
        hint = (" The scan matches were not confirmed by the point-to-line refinement: the "
                "scans have too little straight structure (walls) for the scan matcher; "
                "record among walls." if unconfirmed and len(inputs.laser_from) == 0 else "")
        raise CalibrationError(
            f"the graph has {len(inputs.odo_from)} odometry and {len(inputs.laser_from)} "
            f"laser edges; both are needed.{hint} Rejections: {rejections or 'none'}"
        )
    nominal = np.array(params.calibration_vector())
    prior_sigma = graph_mod.prior_sigmas(nominal, config.graph)
    problem = graph_mod.build_problem(inputs, params, nominal, correct_dilution=correct_dilution,
                                      config=config.graph, linear=config.linear)
    # Judged at the start (nominal calibration, poses settled on it): observability is a
    # property of the motion, not of one noise realisation; at a fitted optimum an
    # undetermined direction could wander to where the curvature looks informative.
    observability = Observability.of_settled_problem(problem, prior_sigma, config.observability)
    # An undetermined direction (standing still, straight lines only, spinning in place)
    # would drift to fit noise, and with it the noise models that depend on it: it is held
    # at nominal. The parameters it moves are reported at nominal with their prior σ.
    locks = observability.lock(nominal)
    problem.factors.extend(locks)
    result, scales = solve_with_variance_components(problem, progress=progress,
                                                    config=config.solver)
    if not all(observability.observable):
        observability, result, scales = _judged_again(problem, observability, locks, result,
                                                      scales, nominal, prior_sigma, progress,
                                                      config)
    # The step a continued solve would still take, from the factorisation the covariance
    # needs anyway: the iteration cap alone says nothing about whether the answer moved.
    remaining, lu = remaining_step(problem, result.values, ["odometry", "laser"])
    values = result.values
    # One linearisation and solve at the answer for the three covariances.
    blocks = ["odometry", "laser"]
    influence = Influence.of(problem, values, blocks, lu)
    model_cov = observability.reported_covariance(influence.marginal)
    correlated_cov, _ = chain_correlated_covariance(problem, values, blocks, influence=influence,
                                                    config=config.solver)
    cov = observability.reported_covariance(
        _at_least(correlated_cov, sandwich_covariance(problem, values, blocks, influence=influence)))
    estimate = observability.reported(graph_mod.calibration_of(values), nominal)
    sigma = np.sqrt(np.diag(cov))
    if not np.all(np.isfinite(estimate)) or not np.all(np.isfinite(sigma)):
        raise CalibrationError("the solver produced a non-finite estimate; the data is degenerate")
    return CalibrationResult(
        estimate=graph_mod.as_dict(estimate),
        sigma=graph_mod.as_dict(sigma),
        covariance=cov,
        model_covariance=model_cov,
        nominal=graph_mod.as_dict(nominal),
        observable=observability.as_dict(),
        scans_used=len(keyframes),
        duration_s=float(inputs.stamps[-1] - inputs.stamps[0]),
        residual_rms=residual_rms(problem, values),
        variance_scales={k: v for k, v in scales.items()},
        iterations=result.iterations,
        converged=bool(result.converged or np.all(
            np.abs(remaining) < config.estimator.converged_step_sigma * sigma)),
        stamps=inputs.stamps,
        poses=values["poses"],
        inputs=inputs,
        problem=problem,
        rejections=rejections or Rejections(),
        observability=observability,
        wheel_noise_correction=dilution.summary(problem, values, observability.as_dict()),
    )
