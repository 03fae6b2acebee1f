"""Residual diagnosis: is the calibrated model enough, and if not, which effects are missing?

    base fit → residual tests (whiteness, dependence on regressors)        structure
             → stepwise selection of library effects, each judged on       selection, evidence,
               held-out time blocks                                        cross_validation
             → refit with the selected effects → what is still unexplained  report, figures

Selection never rests on the in-sample cost (an extra parameter always lowers it). An
effect joins the model only if, fitted on top of the effects already selected, (1) it
lowers the held-out error of time-block cross-validation: the calibration and effects
are fitted on all but one fold of the recording (a contiguous block for mean effects,
blocks spread over the run for noise effects: SelectionConfig), and the laser-vs-odometry
disagreement of the held-out fold's edges is scored (disagreement.py), and (2) its
likelihood-ratio statistic on the whole recording clears the BIC penalty dim·ln(edges)
(for an effect found by a search, the held-out likelihood ratio against ln(edges)). Of
several that pass in a round, mean effects before noise effects and the simplest within
one standard error of the best joins; an earlier one that no longer passes on top of
the others leaves (selection.stepwise_selection).
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np

from sclam_ros.core import graph as graph_mod
from sclam_ros.core.estimator import calibrate_keyframes
from sclam_ros.core.params import CALIBRATION_KEYS
from sclam_ros.diagnosis import identifiability, report as report_mod
from sclam_ros.diagnosis.config import DiagnoseConfig
from sclam_ros.diagnosis.cross_validation import Models, time_block_folds
from sclam_ros.diagnosis.disagreement import OdometryCovariance, fitted_stamp_jitter
from sclam_ros.diagnosis.effects import LIBRARY, EffectData
from sclam_ros.diagnosis.evidence import effect_value
from sclam_ros.diagnosis.fitting import Fit, component_residuals, fit_effects, paired_edges
from sclam_ros.diagnosis.regressors import pose_motion, regressors
from sclam_ros.diagnosis.selection import stepwise_selection
from sclam_ros.diagnosis.structure import name_structure, residual_tests, significant
from sclam_ros.diagnosis.wall_map import WallMap


@dataclass
class Diagnosis:
    report: dict  # the JSON
    residuals_before: dict = field(repr=False, default=None)
    residuals_after: dict = field(repr=False, default=None)
    regressors: dict = field(repr=False, default=None)
    edge_of: dict = field(repr=False, default=None)
    tests_before: list = field(repr=False, default=None)
    tests_after: list = field(repr=False, default=None)
    config: DiagnoseConfig = field(repr=False, default_factory=DiagnoseConfig)  # what it ran with


def _of_the_model(test) -> bool:
    """Whether a significant residual test is structure the model leaves unexplained: any
    memory beyond lag 1, and the odometry residuals' dependence on a regressor. The scan
    matches' residuals depend on the change of wheel speed and the angular acceleration on
    some routes with no effect at all (a scan matcher converges a little short of a motion
    that changed since the last scan), and they are not what the library's effects or a
    missing one of the robot would show first: a cause in the wheels or the clocks moves
    the odometry residuals, which the graph weighs less."""
    return test["regressor"] == "lag" or test["component"].startswith("odometry.")


def _brief(test) -> dict:
    return {k: test[k] for k in ("component", "regressor", "strength")}


def _extended_fit(models: Models, selected):
    """The selected effects fitted together (variance components re-estimated), with the
    final value and σ of each."""
    mech, _ = models.split_effects(selected)
    ext = fit_effects(models.base, mech, variance_components=True) if mech else models.base
    noise = models.fit_whole(selected)[1]
    final = {n: effect_value(models, ext, noise, n) for n in selected}
    return ext, final


def diagnose_keyframes(keyframes, params, effect_names=None, folds=None, noise_folds=None,
                       progress=None, config: DiagnoseConfig = DiagnoseConfig()) -> Diagnosis:
    """Diagnose the recording's `keyframes` under `params`, trying `effect_names` (default:
    the whole library). `folds` / `noise_folds`, when given, replace config.selection's."""
    say = progress or (lambda message: None)
    changes = {k: v for k, v in (("folds", folds), ("noise_folds", noise_folds)) if v is not None}
    if changes:
        config = dataclasses.replace(config, selection=dataclasses.replace(config.selection, **changes))
    selection = config.selection
    names = list(effect_names or LIBRARY)
    say("fitting the base model")
    # Without the wheel noise's dilution correction (core/dilution.py): models are compared
    # by their likelihood, which its linear cost term is not, and the term is derived for
    # the stated wheel noise, not for the noise effects that rescale it.
    base_result = calibrate_keyframes(keyframes, params, correct_dilution=False)
    merged = graph_mod.merge_keyframes(keyframes, params.keyframe_interval)
    inputs = base_result.inputs
    problem = base_result.problem
    base = Fit(problem, problem.values, dict(problem.scales), problem.cost(problem.values))
    nominal = np.array(params.calibration_vector())
    data = EffectData.from_keyframes(keyframes, inputs.stamps, positions=base.values["poses"][:, :2])
    data.walls = WallMap.from_keyframes(keyframes, inputs.stamps, base.values["poses"],
                                        base.values["laser"][0], config.walls)
    wheel_angles = np.array([kf.wheel_angles for kf in merged], float).reshape(-1, 2)
    edges = paired_edges(inputs)
    odo_cov = OdometryCovariance.of(inputs, params, nominal[:3])
    # The residual tests take the motion from the poses: the wheels' own would carry the
    # wheel noise that the odometry residuals are made of (regressors.regressors).
    moved = pose_motion(inputs, base.values["poses"])
    regs = regressors(inputs, data, wheel_angles, base.values["odometry"][0],
                      base.values["poses"], motion=moved)
    odo_pos = {int(a): n for n, a in enumerate(inputs.odo_from)}
    edge_reg = np.array([odo_pos[int(a)] for a in edges.pose_i], int)
    before = component_residuals(problem, base.values, edges)
    edge_of = {c: edge_reg for c in before}
    tests_before = residual_tests(before, regs, edge_of, config.structure)

    say(f"{selection.folds}-fold time-block cross-validation ({selection.noise_folds} spread "
        "folds for noise effects)")
    fold_args = (inputs, edges, base, params, nominal, base_result.observability)
    models = Models(data, inputs, edges, odo_cov, base, time_block_folds(*fold_args, selection.folds),
                    time_block_folds(*fold_args, selection.noise_folds,
                                     blocks_per_fold=selection.noise_fold_blocks),
                    regs, edge_reg, config)
    if config.noise.stamp_jitter:
        models.jitter = fitted_stamp_jitter(base, inputs, edges, odo_cov, data.wheel_speeds,
                                            config.noise.log_range)
        say(f"the scans' timing noise: {1e3 * models.jitter.sigma:.2f} ms (1σ, held in every "
            "model compared)")
    n_edges = len(inputs.odo_from) + len(inputs.laser_from)
    selected, evidence, pairs = stepwise_selection(models, names, n_edges, say)
    base_error = float(np.mean(models.heldout_nll([])))
    ext_error = float(np.mean(models.heldout_nll(selected)))

    say("refitting with the selected effects: " + (", ".join(selected) or "none"))
    ext, final = _extended_fit(models, selected)
    after = component_residuals(ext.problem, ext.values, edges)
    tests_after = residual_tests(after, regs, edge_of, config.structure)
    structure_after = significant(tests_after, config.structure)
    shift = identifiability.calibration_shift(base, ext, CALIBRATION_KEYS) if selected else {}
    report = {
        "base": report_mod.model_summary(base, base_error),
        # s, 1σ of the scans' timing noise held in every model (stamp_jitter.py); null: not modelled
        "timing_noise_s": None if models.jitter is None else models.jitter.sigma,
        "extended": report_mod.model_summary(ext, ext_error),
        "error_metric": report_mod.error_metric(selection),
        "effects": report_mod.effects_json(names, evidence, selected, final),
        "unexplained": [_brief(t) for t in structure_after if _of_the_model(t)],
        # The scan matches' residuals against how the robot moves: the scan matcher's
        # own error (docs/diagnose.md), told but not counted as the model's.
        "scan_matcher_structure": [_brief(t) for t in structure_after if not _of_the_model(t)],
        # The regressors that explain most of what is left (over the structured
        # components), with the fraction each explains.
        "unexplained_cause": name_structure(
            {c: r for c, r in after.items() if c.startswith("odometry.")}, regs, edge_reg,
            moved, config.structure),
        "not_separable": pairs,
        "calibration_shift_sigma": shift,
        "warnings": report_mod.warnings(selected, shift, pairs,
                                        config.identifiability.max_shift_sigma),
    }
    return Diagnosis(report, before, after, regs, edge_of, tests_before, tests_after, config)
