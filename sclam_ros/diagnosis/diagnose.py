"""Residual diagnosis: is the calibrated model enough, and if not, which effects are missing?

    base fit → residual tests (whiteness, dependence on regressors)
             → stepwise selection of library effects, each judged on held-out time blocks
             → refit with the selected effects → what is still unexplained

Selection never rests on the in-sample cost (an extra parameter always lowers it). An
effect joins the model only if, fitted on top of the effects already selected, (1) it
lowers the held-out error of time-block cross-validation: the calibration and effects
are fitted on all but one contiguous block of the recording, and the laser-vs-odometry
disagreement of the held-out block's edges is scored, and (2) its likelihood-ratio
statistic on the whole recording clears the BIC penalty dim·ln(edges). Of several that
pass in a round, the simplest within one standard error of the best joins; an earlier
one that no longer passes on top of the others leaves (see _stepwise_selection).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import stats

from sclam_ros.core import graph as graph_mod
from sclam_ros.core import kinematics, se2
from sclam_ros.diagnosis.effects import LIBRARY, EffectData
from sclam_ros.diagnosis.effects.model import EffectLaserFactor, EffectOdometryFactor, extend_problem
from sclam_ros.core.estimator import calibrate_keyframes, residual_rms
from sclam_ros.core.params import CALIBRATION_KEYS
from sclam_ros.core.solver import levenberg_marquardt, marginal_covariance, solve_with_variance_components

ERROR_METRIC = (
    "held-out mean negative log-likelihood per edge (nats, constant dropped) of the "
    "laser-vs-odometry disagreement d = (l⁻¹ ∘ K(u; k, effects) ∘ l) ⊖ z of the edges of "
    "each held-out time block ({folds}-fold contiguous-block cross-validation, calibration "
    "and effects fitted on the other blocks): 0.5·(ρ(dᵀΣ⁻¹d) + ln det Σ), Σ the fitted "
    "odometry + scan-match covariance in the laser frame, ρ the graph's Cauchy kernel (c = 3)"
)

CAUCHY_C = 3.0
# Effects tried by default: the whole library. scan_distortion used to be a common scale
# (1 + c) of all scan matches, confounded with the wheel radii (c = −6.5 % on a run
# without distortion); it now models a moving sweep by terms the radii cannot mimic and
# stays unselected on runs without a sweep (simulated 90 s runs, none, 20 ms clock offset,
# lateral slip: held-out gain −0.017, −0.050, −0.063 nats/edge, likelihood ratio ≤ 2.5
# against a BIC penalty of 23.6).
DEFAULT_CANDIDATES = ("time_offset", "lateral_slip", "radius_drift", "floor_noise",
                      "scan_distortion")
FOLDS = 5
# Residual-regressor dependence counts as structure when its correlation is this
# strong and significant after a Bonferroni correction over all tests at this level.
MIN_STRENGTH = 0.2
ALPHA = 0.01
LJUNG_BOX_LAGS = 10
RESIDUAL_CLIP = 3.0  # whitened σ


@dataclass
class Fit:
    problem: object
    values: object
    scales: dict
    cost: float


# --- edges, regressors, residual tests ------------------------------------------------


@dataclass
class Edges:
    """Edges with both an odometry and a chained laser measurement (the scored ones)."""

    odo_index: np.ndarray  # into inputs.odo_*
    laser_index: np.ndarray  # into inputs.laser_*
    pose_i: np.ndarray
    pose_j: np.ndarray


def paired_edges(inputs) -> Edges:
    laser_of = {(int(a), int(b)): n for n, (a, b) in enumerate(zip(inputs.laser_from, inputs.laser_to))}
    odo, las = [], []
    for n, a in enumerate(inputs.odo_from):
        m = laser_of.get((int(a), int(a) + 1))
        if m is not None:
            odo.append(n)
            las.append(m)
    odo, las = np.array(odo, int), np.array(las, int)
    return Edges(odo, las, inputs.odo_from[odo], inputs.odo_from[odo] + 1)


def regressors(inputs, data: EffectData, wheel_angles, k, poses) -> dict:
    """Candidate explanations per odometry edge, name -> (m_o,) array."""
    i, j = inputs.odo_from, inputs.odo_from + 1
    t = data.stamps
    dt = np.maximum(t[j] - t[i], 1e-3)
    s, theta = kinematics.arc_length_and_rotation(inputs.odo_dphi, k)
    v, w = s / dt, theta / dt
    mid = 0.5 * (t[i] + t[j])
    order = np.argsort(mid)
    accel = np.zeros_like(v)
    alpha = np.zeros_like(w)
    if len(v) > 2:
        accel[order] = np.gradient(v[order], mid[order])
        alpha[order] = np.gradient(w[order], mid[order])
    r = np.asarray(k, float)
    body_w = (data.wheel_speeds[:, 1] * r[1] - data.wheel_speeds[:, 0] * r[0]) / r[2]
    pos = 0.5 * (poses[i, :2] + poses[j, :2])
    return {
        "v": v,
        "omega": w,
        "abs_omega": np.abs(w),
        "v_times_omega": v * w,
        "acceleration": accel,
        "angular_acceleration": alpha,
        "wheel_speed_change": body_w[j] - body_w[i],  # what an encoder/laser clock offset scales
        "time": mid - t[0],
        "distance": np.cumsum(np.abs(s)),
        "x": pos[:, 0],
        "y": pos[:, 1],
        # A radius varying once per wheel revolution, r·(1 + a·sin(φ + c)), changes an
        # edge's wheel rotation by ≈ a·(cos(φ_j + c) − cos(φ_i + c)): a combination of these
        # two differences per wheel, whatever the (unknown) phase c.
        "wheel_angle_left": np.sin(wheel_angles[j, 0]) - np.sin(wheel_angles[i, 0]),
        "wheel_angle_left_cos": np.cos(wheel_angles[j, 0]) - np.cos(wheel_angles[i, 0]),
        "wheel_angle_right": np.sin(wheel_angles[j, 1]) - np.sin(wheel_angles[i, 1]),
        "wheel_angle_right_cos": np.cos(wheel_angles[j, 1]) - np.cos(wheel_angles[i, 1]),
        "speed_squared": v * np.abs(v),  # forward slip growing with speed
    }


def ljung_box(series, lags=LJUNG_BOX_LAGS):
    """(Q, p) of the Ljung-Box test of no autocorrelation up to `lags`."""
    x = np.asarray(series, float) - np.mean(series)
    n = len(x)
    lags = min(lags, n // 4)
    denom = float(np.dot(x, x))
    if lags < 1 or denom <= 0:
        return 0.0, 1.0
    rho = np.array([np.dot(x[:-h], x[h:]) / denom for h in range(1, lags + 1)])
    q = n * (n + 2) * np.sum(rho**2 / (n - np.arange(1, lags + 1)))
    return float(q), float(stats.chi2.sf(q, lags))


def residual_tests(residuals: dict, regs: dict, edge_of: dict) -> list:
    """Dependence of every residual component on every regressor, and whiteness.

    residuals: component name -> (m,) values; edge_of: component name -> (m,) index into
    the regressor arrays. Strength is |Pearson r| of the whitened residual, clipped at ±3σ
    so an odd failed scan match cannot dominate, with its two-sided p-value. (Not a rank
    correlation: most edges drive straight, and ranking their near-zero ω by its noise
    showed |ρ| ≈ 0.5 "structure" on simulated runs with no effect at all.) Whiteness:
    Ljung-Box over the first 10 lags (regressor "lag").
    """
    out = []
    for comp, res in residuals.items():
        idx = edge_of[comp]
        for name, reg in regs.items():
            x = reg[idx]
            if np.ptp(x) == 0 or len(x) < 10:
                continue
            rho, p = stats.pearsonr(x, np.clip(res, -RESIDUAL_CLIP, RESIDUAL_CLIP))
            if np.isfinite(rho):
                out.append({"component": comp, "regressor": name, "strength": float(abs(rho)),
                            "p_value": float(p)})
        q, p = ljung_box(res)
        n = len(res)
        out.append({"component": comp, "regressor": "lag", "strength": float(
            np.sqrt(q / max(n, 1))), "p_value": p})
    return out


def significant(tests: list) -> list:
    threshold = ALPHA / max(len(tests), 1)
    keep = [t for t in tests if t["p_value"] < threshold
            and (t["regressor"] == "lag" or t["strength"] >= MIN_STRENGTH)]
    return sorted(keep, key=lambda t: -t["strength"])


# --- fitting ----------------------------------------------------------------------------


def _component_residuals(problem, values, edges: Edges):
    """Whitened residual components (the stated noise grows with the wheel angle turned,
    so raw residuals would correlate with speed through their spread alone) of the scored edges, name -> (m,), all indexed like edges."""
    out = {}
    for f in problem.factors:
        if f.name in ("odometry", "laser") and len(f):
            lin = f.linearize(values)
            r = np.einsum("mij,mj->mi", lin.sqrt_information, lin.residual)
            pick = edges.odo_index if f.name == "odometry" else edges.laser_index
            for c, axis in enumerate(("x", "y", "theta")):
                out[f"{f.name}.{axis}"] = r[pick, c]
    return out


def _subset(inputs, keep_pose_edges):
    """GraphInputs with only the edges whose both poses satisfy the mask."""
    o = keep_pose_edges[inputs.odo_from] & keep_pose_edges[inputs.odo_from + 1]
    la = keep_pose_edges[inputs.laser_from] & keep_pose_edges[inputs.laser_to]
    return graph_mod.GraphInputs(inputs.stamps, inputs.odo_from[o], inputs.odo_dphi[o],
                                 inputs.laser_from[la], inputs.laser_to[la], inputs.laser_z[la],
                                 inputs.laser_info[la],
                                 odo_parts=None if inputs.odo_parts is None else inputs.odo_parts[o])


def _fit_base(inputs, params, nominal, observability, poses=None) -> Fit:
    """The base model on `inputs`, with the full run's undetermined directions locked."""
    problem = graph_mod.build_problem(inputs, params, nominal, poses=poses)
    problem.factors.extend(observability.lock(nominal))
    result, scales = solve_with_variance_components(problem)
    return Fit(problem, result.values, scales, result.final_cost)


def _fit_effects(base: Fit, effects, variance_components=False) -> Fit:
    problem = extend_problem(base.problem, effects)
    problem.values = problem.values.copy()
    for name in base.values:
        problem.values[name] = base.values[name].copy()
    problem.scales = dict(base.scales)
    if variance_components:
        result, scales = solve_with_variance_components(problem)
    else:
        result, scales = levenberg_marquardt(problem), dict(base.scales)
    return Fit(problem, result.values, scales, result.final_cost)


# --- held-out scoring ---------------------------------------------------------------------


@dataclass
class Disagreement:
    """Per-edge laser-vs-odometry disagreement d and the two parts of its covariance, so a
    noise model can rescale the odometry part without recomputing anything else."""

    d: np.ndarray  # (m, 3) laser frame
    odometry_cov: np.ndarray  # (m, 3, 3) J Σ_o Jᵀ, the odometry's share
    laser_cov: np.ndarray  # (m, 3, 3) the scan match's share

    def nll(self, odometry_scale=1.0):
        """Per-edge NLL with the odometry covariance multiplied by odometry_scale ((m,) or
        a number)."""
        scale = np.reshape(np.asarray(odometry_scale, float), (-1, 1, 1))
        cov = self.odometry_cov * scale + self.laser_cov
        sq = np.einsum("mi,mij,mj->m", self.d, np.linalg.inv(cov), self.d)
        rho = CAUCHY_C**2 * np.log1p(sq / CAUCHY_C**2)
        return 0.5 * (rho + np.linalg.slogdet(cov)[1])


def disagreement(fit: Fit, effects, inputs, edges: Edges, odo_cov) -> Disagreement:
    """d = (l⁻¹ ∘ K(u; k, effects) ∘ l) ⊖ z' of the edges, with its covariance split."""
    values = fit.values
    mech = [e for e in effects if e.kind != "noise"]
    oi, li = edges.odo_index, edges.laser_index
    odo = EffectOdometryFactor(edges.pose_i, edges.pose_j, inputs.odo_dphi[oi],
                               np.tile(np.eye(3), (len(oi), 1, 1)), mech,
                               parts=None if inputs.odo_parts is None else inputs.odo_parts[oi])
    las = EffectLaserFactor(edges.pose_i, edges.pose_j, inputs.laser_z[li],
                            inputs.laser_info[li], mech)
    motion, _, _ = odo.predicted_motion_with_jacobians(values)
    z, _ = las.corrected_z(values)
    mount = values["laser"][0]
    a, a_m = se2.compose_with_jacobians(motion, mount)[:2]
    zp, _, zp_a = se2.compose_with_jacobians(np.broadcast_to(se2.inverse(mount), a.shape), a)
    d, d_zp, d_z = se2.between_with_jacobians(zp, z)
    j_m = d_zp @ zp_a @ a_m
    cov_o = odo_cov[oi] * fit.scales.get("odometry", 1.0)
    cov_z = np.linalg.inv(inputs.laser_info[li]) * fit.scales.get("laser", 1.0)
    return Disagreement(d, j_m @ cov_o @ np.swapaxes(j_m, 1, 2),
                        d_z @ cov_z @ np.swapaxes(d_z, 1, 2))


def edge_nll(fit: Fit, effects, inputs, edges: Edges, odo_cov, noise=None):
    """Per-edge negative log-likelihood of the laser-vs-odometry disagreement."""
    dis = disagreement(fit, effects, inputs, edges, odo_cov)
    return dis.nll(1.0 if noise is None else noise.scale_of(edges.pose_i, edges.pose_j))


def _fit_noise(effect, fit: Fit, mech, inputs, edges: Edges, odo_cov):
    """Fit a noise effect to the disagreement of `edges` under `fit`; the NLL before and
    after (per edge)."""
    dis = disagreement(fit, mech, inputs, edges, odo_cov)
    effect.fit(edges.pose_i, edges.pose_j, dis.nll)
    return dis.nll(), dis.nll(effect.scale_of(edges.pose_i, edges.pose_j))


# --- models: a set of effects, fitted on the whole run and on the folds --------------------


@dataclass
class _Fold:
    test: Edges  # the held-out block's edges
    train_edges: Edges
    train: Fit  # the base model fitted without the held-out block


def _edges_where(edges: Edges, keep) -> Edges:
    return Edges(edges.odo_index[keep], edges.laser_index[keep], edges.pose_i[keep],
                 edges.pose_j[keep])


@dataclass
class _Models:
    """Fits of effect sets, each done once: on the whole run (values, σ, likelihood ratio)
    and per held-out fold (the held-out error)."""

    data: EffectData
    inputs: object
    edges: Edges
    odo_cov: np.ndarray
    base: Fit
    folds: list
    whole: dict = field(default_factory=dict)
    heldout: dict = field(default_factory=dict)

    def effects(self, names):
        return [LIBRARY[n](self.data) for n in names]

    def split_effects(self, names):
        """(mechanical effects, the noise effect or None), fresh instances of `names`."""
        effects = self.effects(names)
        return ([e for e in effects if e.kind != "noise"],
                next((e for e in effects if e.kind == "noise"), None))

    def fit_whole(self, names):
        """(Fit of the mechanical effects, fitted noise effect or None, whole-run cost)."""
        key = tuple(names)
        if key not in self.whole:
            mech, noise = self.split_effects(names)
            fit = _fit_effects(self.base, mech) if mech else self.base
            cost = fit.cost
            if noise is not None:  # 2·ΔNLL: the same scale as the graph's χ²-type cost
                before, after = _fit_noise(noise, fit, mech, self.inputs, self.edges, self.odo_cov)
                cost -= 2.0 * float(np.sum(before - after))
            self.whole[key] = (fit, noise, cost)
        return self.whole[key]

    def heldout_nll(self, names):
        """Per-edge NLL of every held-out block, concatenated in fold order."""
        key = tuple(names)
        if key not in self.heldout:
            per_fold = []
            for fold in self.folds:
                mech, noise = self.split_effects(names)  # a noise effect is fitted per fold
                fit = _fit_effects(fold.train, mech) if mech else fold.train
                if noise is not None:
                    _fit_noise(noise, fit, mech, self.inputs, fold.train_edges, self.odo_cov)
                per_fold.append(edge_nll(fit, mech, self.inputs, fold.test, self.odo_cov, noise))
            self.heldout[key] = np.concatenate(per_fold)
        return self.heldout[key]


def _time_block_folds(inputs, edges, base, params, nominal, observability, folds) -> list:
    out = []
    for block in np.array_split(np.arange(inputs.size), folds):
        held = np.zeros(inputs.size, bool)
        held[block] = True
        test = held[edges.pose_j] & held[edges.pose_i]
        if not test.any():
            continue
        train = _fit_base(_subset(inputs, ~held), params, nominal, observability,
                          poses=base.values["poses"])
        out.append(_Fold(_edges_where(edges, test), _edges_where(edges, ~held[edges.pose_j]
                                                                  & ~held[edges.pose_i]), train))
    return out


def _evaluate(models: _Models, selected, name, n_edges) -> dict:
    """Evidence for adding effect `name` to the `selected` ones."""
    fit, noise, cost = models.fit_whole(selected + [name])
    cost_before = models.fit_whole(selected)[2]
    gain = models.heldout_nll(selected) - models.heldout_nll(selected + [name])
    dim = models.effects([name])[0].dim
    lr = float(cost_before - cost)
    bic = dim * np.log(n_edges)
    value, sigma, params = _effect_value(models, fit, noise, name)
    return {"name": name, "value": value, "sigma": sigma, "params": params,
            "added_to": list(selected), "gain": gain, "lr": lr, "bic": float(bic),
            "heldout_error": float(np.mean(models.heldout_nll(selected + [name]))),
            "passes": bool(gain.mean() > 0 and lr > bic)}


def _effect_value(models: _Models, fit: Fit, noise, name):
    """(reported value, its σ, the parameter vector) of effect `name` in a fit."""
    if noise is not None and noise.name == name:
        return noise.value(), None, None
    effect = LIBRARY[name](models.data)
    p = fit.values[name][0]
    cov = marginal_covariance(fit.problem, fit.values, [name])
    pick = int(np.argmax(np.abs(p))) if effect.dim > 1 else 0
    return effect.value(p), float(np.sqrt(cov[pick, pick])), p.tolist()


def _stepwise_selection(models: _Models, names, n_edges, say):
    """Stepwise selection. Each round, every remaining effect is fitted on top of the ones
    selected so far, and one of those that pass (held-out gain > 0 and likelihood ratio >
    BIC penalty) joins: the simplest of those whose held-out error is within one standard
    error of the best's (the one-standard-error rule). Then each earlier selected effect is
    tried on top of the others, and leaves for good if it no longer passes: an effect that
    a later, larger one contains (a clock offset in scan_distortion's delay) must not stay
    to share its parameter with it. Trying effects on top of the selected ones, not only
    against the base model, lets an effect whose signature is buried under a larger one
    show, and keeps one that only re-explains a selected one out.

    Returns the selected names and, per effect, the evidence of the last time it was tried.
    """
    selected, evidence = [], {}
    remaining = list(names)
    while remaining:
        say("trying " + ", ".join(remaining) + (" on top of " + ", ".join(selected)
                                                 if selected else ""))
        round_ = {n: _evaluate(models, selected, n, n_edges) for n in remaining}
        evidence.update(round_)
        passing = [n for n in remaining if round_[n]["passes"]]
        if not passing:
            break
        chosen = _simplest_near_best(models, selected, passing, round_)
        selected.append(chosen)
        remaining.remove(chosen)
        for earlier in selected[:-1]:
            others = [n for n in selected if n != earlier]
            again = _evaluate(models, others, earlier, n_edges)
            if not again["passes"]:
                say(f"dropping {earlier}: no longer adds to " + ", ".join(others))
                evidence[earlier] = again
                selected.remove(earlier)
    return selected, evidence


def _simplest_near_best(models: _Models, selected, passing, round_) -> str:
    best = max(passing, key=lambda n: round_[n]["gain"].mean())
    best_nll = models.heldout_nll(selected + [best])

    def near(name):
        worse = models.heldout_nll(selected + [name]) - best_nll
        return worse.mean() <= worse.std(ddof=1) / np.sqrt(len(worse))

    return min((n for n in passing if near(n)),
               key=lambda n: (models.effects([n])[0].dim, -round_[n]["gain"].mean()))


# --- the diagnosis ---------------------------------------------------------------------------


@dataclass
class Diagnosis:
    report: dict  # the JSON
    residuals_before: dict = field(repr=False, default=None)
    residuals_after: dict = field(repr=False, default=None)
    regressors: dict = field(repr=False, default=None)
    edge_of: dict = field(repr=False, default=None)
    tests_before: list = field(repr=False, default=None)
    tests_after: list = field(repr=False, default=None)


def _effect_json(ev: dict, selected: bool, base_error: float) -> dict:
    gain = ev["gain"]
    return {
        "name": ev["name"], "selected": selected, "value": ev["value"], "sigma": ev["sigma"],
        "evidence": {
            "heldout_error": ev["heldout_error"], "heldout_error_base": base_error,
            "heldout_gain_per_edge": float(gain.mean()),
            "heldout_gain_stderr": float(gain.std(ddof=1) / np.sqrt(len(gain))),
            "likelihood_ratio": ev["lr"], "bic_penalty": ev["bic"],
            "added_to": ev["added_to"],
            "units": LIBRARY[ev["name"]].units,
            **({"params": ev["params"]} if ev["params"] is not None else {}),
        },
    }


def _extended_fit(models: _Models, selected):
    """The selected effects fitted together (variance components re-estimated), with the
    final value and σ of each."""
    mech, _ = models.split_effects(selected)
    ext = _fit_effects(models.base, mech, variance_components=True) if mech else models.base
    noise = models.fit_whole(selected)[1]
    final = {n: _effect_value(models, ext, noise, n) for n in selected}
    return ext, final


def diagnose_keyframes(keyframes, params, effect_names=None, folds=FOLDS, progress=None) -> Diagnosis:
    say = progress or (lambda message: None)
    names = list(effect_names or DEFAULT_CANDIDATES)
    say("fitting the base model")
    base_result = calibrate_keyframes(keyframes, params)
    merged = graph_mod.merge_keyframes(keyframes, params.keyframe_interval)
    inputs = base_result.inputs
    problem = base_result.problem
    base = Fit(problem, problem.values, dict(problem.scales), problem.cost(problem.values))
    nominal = np.array([getattr(params, k) for k in CALIBRATION_KEYS])
    data = EffectData.from_keyframes(keyframes, inputs.stamps, positions=base.values["poses"][:, :2])
    wheel_angles = np.array([kf.wheel_angles for kf in merged], float).reshape(-1, 2)
    edges = paired_edges(inputs)
    odo_cov = kinematics.motion_covariance(inputs.odo_dphi, nominal[:3], params.wheel_noise,
                                           graph_mod.encoder_variance_floor(params),
                                           params.lateral_noise)
    regs = regressors(inputs, data, wheel_angles, base.values["odometry"][0], base.values["poses"])
    odo_pos = {int(a): n for n, a in enumerate(inputs.odo_from)}
    edge_reg = np.array([odo_pos[int(a)] for a in edges.pose_i], int)
    before = _component_residuals(problem, base.values, edges)
    edge_of = {c: edge_reg for c in before}
    tests_before = residual_tests(before, regs, edge_of)

    say(f"{folds}-fold time-block cross-validation")
    models = _Models(data, inputs, edges, odo_cov, base,
                     _time_block_folds(inputs, edges, base, params, nominal,
                                       base_result.observability, folds))
    n_edges = len(inputs.odo_from) + len(inputs.laser_from)
    selected, evidence = _stepwise_selection(models, names, n_edges, say)
    base_error = float(np.mean(models.heldout_nll([])))
    ext_error = float(np.mean(models.heldout_nll(selected)))

    say("refitting with the selected effects: " + (", ".join(selected) or "none"))
    ext, final = _extended_fit(models, selected)
    effects_json = []
    for name in names:
        e = _effect_json(evidence[name], name in selected, base_error)
        if name in final:
            e["value"], e["sigma"] = final[name][:2]
        effects_json.append(e)
    after = _component_residuals(ext.problem, ext.values, edges)
    tests_after = residual_tests(after, regs, edge_of)

    def summary(fit, err):
        rms = residual_rms(fit.problem, fit.values)
        return {
            "params": graph_mod.as_dict(graph_mod.calibration_of(fit.values)),
            "residual_rms": {k: [float(x) for x in v] for k, v in rms.items()
                             if k in ("odometry", "laser")},
            "error": err,
        }

    report = {
        "base": summary(base, base_error),
        "extended": summary(ext, ext_error),
        "error_metric": ERROR_METRIC.format(folds=folds),
        "effects": effects_json,
        "unexplained": [{k: t[k] for k in ("component", "regressor", "strength")}
                        for t in significant(tests_after)],
    }
    return Diagnosis(report, before, after, regs, edge_of, tests_before, tests_after)


# --- figures ------------------------------------------------------------------------------


def write_diagnosis_report(out_dir, diagnosis: Diagnosis, per_figure: int = 6) -> list:
    """PNG per residual component: the residual against its strongest regressors, before
    (base model) and after (extended model) on the same axes."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from pathlib import Path

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = []
    strongest = {}
    for t in sorted(diagnosis.tests_before, key=lambda t: -t["strength"]):
        if t["regressor"] != "lag":
            strongest.setdefault(t["component"], []).append(t)
    for comp, tests in strongest.items():
        tests = tests[:3]
        fig, axes = plt.subplots(1, len(tests), figsize=(4.5 * len(tests), 3.6), squeeze=False)
        idx = diagnosis.edge_of[comp]
        for ax, t in zip(axes[0], tests):
            x = diagnosis.regressors[t["regressor"]][idx]
            ax.plot(x, diagnosis.residuals_before[comp], ".", ms=3, alpha=0.6, label="before (base)")
            ax.plot(x, diagnosis.residuals_after[comp], ".", ms=3, alpha=0.6, label="after (extended)")
            ax.set_xlabel(t["regressor"])
            ax.set_ylabel(f"{comp} (whitened)")
            ax.set_title(f"|ρ| = {t['strength']:.2f} before")
            ax.legend(fontsize=7)
        fig.tight_layout()
        path = out / f"residual_{comp.replace('.', '_')}.png"
        fig.savefig(path, dpi=90)
        plt.close(fig)
        paths.append(path)
    return paths
