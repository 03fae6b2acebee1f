"""Cross-run prediction: a model fitted on one recording, scored on another of the same robot.

    fit_models(keyframes of A, effects) → base and extended FittedModel (calibration,
                                          effect parameters, noise scales)
    predict_error(model, keyframes of B) → per-edge NLL of B's laser-vs-odometry disagreement

Time-block cross-validation (diagnose) holds out part of the same drive; a calibration is
meant to serve the next drive. Here the whole of B is held out: nothing of B enters the
fit, and the error is diagnose's held-out metric (disagreement.edge_nll) over every paired edge
of B. The effects read B's own stamps and wheel speeds with A's parameters: a clock offset
or a lateral-slip gain is a property of the robot, not of the drive, and so is the scans'
timing noise (stamp_jitter.py; A's 1σ with B's wheel speeds). Noise effects
(floor_noise) are not carried over: their regions are cells of A's map, which B's frame
does not share; the extended model is scored with its mechanical effects only.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sclam_ros.core import graph as graph_mod
from sclam_ros.diagnosis.config import NoiseConfig
from sclam_ros.diagnosis.disagreement import OdometryCovariance, edge_nll, fitted_stamp_jitter
from sclam_ros.diagnosis.effects import LIBRARY, EffectData
from sclam_ros.diagnosis.effects.model import extend_problem
from sclam_ros.diagnosis.fitting import Fit, paired_edges
from sclam_ros.diagnosis.stamp_jitter import StampJitter
from sclam_ros.core.estimator import calibrate_keyframes
from sclam_ros.core.variance_components import solve_with_variance_components

CROSS_RUN_METRIC = (
    "error_cross_run: the same per-edge NLL over every paired edge of another recording of "
    "the same robot ({other}), with the calibration, mechanical effects and noise scales "
    "fitted on the whole of this recording (nothing of the other recording enters the fit; "
    "noise effects, being regions of this recording's map, are not carried over)"
)


@dataclass
class FittedModel:
    """What carries over to another recording: no poses, only the robot's parameters."""

    effects: tuple  # names of the mechanical effects, in the order they chain
    values: dict  # block name -> (1, dim): "odometry", "laser" and one per effect
    scales: dict  # variance factor per edge type
    timing_noise: float = 0.0  # s, 1σ of the scans' timing noise (stamp_jitter.py)


def mechanical(effect_names) -> tuple:
    return tuple(n for n in effect_names if LIBRARY[n].kind != "noise")


def graph_inputs(keyframes, params) -> graph_mod.GraphInputs:
    """The merged edges the calibration graph of this recording is built from."""
    return graph_mod.GraphInputs.from_keyframes(
        graph_mod.merge_keyframes(keyframes, params.keyframe_interval))


def _carried_over(values, names, scales, timing_noise) -> FittedModel:
    blocks = {name: np.array(values[name]) for name in ("odometry", "laser", *names)}
    return FittedModel(tuple(names), blocks, dict(scales), timing_noise)


def fit_models(keyframes, params, effect_names=()) -> tuple:
    """(base, extended) fitted on the whole recording as diagnose fits them: the base
    graph solved with variance components, then the mechanical effects added and the
    graph solved again from there. Without mechanical effects both are the base."""
    result = calibrate_keyframes(keyframes, params, correct_dilution=False)  # as diagnose
    inputs, problem = result.inputs, result.problem
    data = EffectData.from_keyframes(keyframes, inputs.stamps)
    fit = Fit(problem, problem.values, dict(problem.scales), float("nan"))
    odo_cov = OdometryCovariance.of(inputs, params, np.array(params.calibration_vector()[:3]))
    timing = fitted_stamp_jitter(fit, inputs, paired_edges(inputs), odo_cov, data.wheel_speeds,
                                 NoiseConfig().log_range).sigma
    base = _carried_over(problem.values, (), problem.scales, timing)
    names = mechanical(effect_names)
    if not names:
        return base, base
    extended = extend_problem(problem, [LIBRARY[n](data) for n in names])
    solved, scales = solve_with_variance_components(extended)
    return base, _carried_over(solved.values, names, scales, timing)


def predict_error(model: FittedModel, keyframes, params) -> np.ndarray:
    """Per-edge NLL (nats) of another recording's edges under `model` (disagreement.edge_nll)."""
    inputs = graph_inputs(keyframes, params)
    data = EffectData.from_keyframes(keyframes, inputs.stamps)
    effects = [LIBRARY[n](data) for n in model.effects]
    # The stated odometry noise at nominal k, exactly as diagnose scores its held-out blocks.
    odo_cov = OdometryCovariance.of(inputs, params, np.array(params.calibration_vector()[:3]))
    fit = Fit(problem=None, values=model.values, scales=model.scales, cost=float("nan"))
    jitter = StampJitter(data.wheel_speeds, model.timing_noise)
    return edge_nll(fit, effects, inputs, paired_edges(inputs), odo_cov, jitter=jitter)


def selected_effects(report) -> list:
    return [e["name"] for e in report["effects"] if e["selected"]]


def cross_run_errors(keyframes, params, other_keyframes, other_params, effect_names) -> dict:
    """Base and extended models fitted on one recording, scored on the other: mean NLL per
    edge of each, and the extended model's paired gain with its standard error (edges
    taken as independent, as diagnose does for its held-out gain)."""
    base_model, ext_model = fit_models(keyframes, params, effect_names)
    base = predict_error(base_model, other_keyframes, other_params)
    ext = predict_error(ext_model, other_keyframes, other_params)
    gain = base - ext
    return {"base": float(base.mean()), "extended": float(ext.mean()), "edges": len(gain),
            "gain": float(gain.mean()),
            "gain_stderr": float(gain.std(ddof=1) / np.sqrt(len(gain))) if len(gain) > 1 else 0.0}


def add_cross_run(report, keyframes, params, other_keyframes, other_params, other_name) -> dict:
    """diagnose's report with the cross-run error of its base and extended models (the
    extended one with the effects diagnose selected) in `base` / `extended`, and the
    metric described in `error_metric`. The top-level keys stay as they are."""
    errors = cross_run_errors(keyframes, params, other_keyframes, other_params,
                              selected_effects(report))
    report["base"]["error_cross_run"] = errors["base"]
    report["extended"]["error_cross_run"] = errors["extended"]
    report["extended"]["cross_run_gain_stderr"] = errors["gain_stderr"]
    report["extended"]["cross_run_edges"] = errors["edges"]
    report["error_metric"] += "; " + CROSS_RUN_METRIC.format(other=other_name)
    return report
