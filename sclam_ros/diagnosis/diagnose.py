"""Residual diagnosis: is the calibrated model enough, and if not, which effects are missing?

    base fit → residual tests (whiteness, dependence on regressors)
             → stepwise selection of library effects, each judged on held-out time blocks
             → refit with the selected effects → what is still unexplained

Selection never rests on the in-sample cost (an extra parameter always lowers it). An
effect joins the model only if, fitted on top of the effects already selected, (1) it
lowers the held-out error of time-block cross-validation: the calibration and effects
are fitted on all but one fold of the recording (a contiguous block for mean effects,
blocks spread over the run for noise effects: SelectionConfig), and the
laser-vs-odometry disagreement of the held-out fold's edges is scored, and (2) its
likelihood-ratio statistic on the whole recording clears the BIC penalty dim·ln(edges)
(for an effect found by a search, the held-out likelihood ratio against ln(edges)). Of
several that pass in a round, mean effects before noise effects and the simplest within
one standard error of the best joins; an earlier one that no longer passes on top of
the others leaves (see _stepwise_selection).
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np

from sclam_ros.core import graph as graph_mod
from sclam_ros.core import kinematics, se2
from sclam_ros.diagnosis.effects import LIBRARY, EffectData
from sclam_ros.diagnosis.effects.model import EffectLaserFactor, EffectOdometryFactor, extend_problem
from sclam_ros.core.covariance import marginal_covariance
from sclam_ros.core.estimator import calibrate_keyframes, residual_rms
from sclam_ros.core.levenberg_marquardt import levenberg_marquardt
from sclam_ros.core.params import CALIBRATION_KEYS
from sclam_ros.core.variance_components import solve_with_variance_components
from sclam_ros.diagnosis import identifiability
from sclam_ros.diagnosis.config import DiagnoseConfig
from sclam_ros.diagnosis.noise_model import combined_scale, fit_noise
from sclam_ros.diagnosis.regressors import regressors
from sclam_ros.diagnosis.wall_map import WallMap
from sclam_ros.diagnosis.structure import (fitted_values, name_structure, regressor_shares,
                                           residual_tests, significant)

ERROR_METRIC = (
    "held-out mean negative log-likelihood per edge (nats, constant dropped) of the "
    "laser-vs-odometry disagreement d = (l⁻¹ ∘ K(u; k, effects) ∘ l) ⊖ z of the edges of "
    "each held-out time block ({folds}-fold contiguous-block cross-validation, calibration "
    "and effects fitted on the other blocks; a noise effect's evidence: {noise_folds} "
    "folds of {spread} blocks each, spread over the run): 0.5·(ρ(dᵀΣ⁻¹d) + ln det Σ), Σ the fitted "
    "odometry + scan-match covariance in the laser frame, ρ the graph's Cauchy kernel (c = {c:g})"
)


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
                                 odo_parts=None if inputs.odo_parts is None else inputs.odo_parts[o],
                                 odo_variance=(None if inputs.odo_variance is None
                                               else inputs.odo_variance[o]),
                                 odo_path_variance=(None if inputs.odo_path_variance is None
                                                    else inputs.odo_path_variance[o]))


def _fit_base(inputs, params, nominal, observability, poses=None) -> Fit:
    """The base model on `inputs`, with the full run's undetermined directions locked."""
    problem = graph_mod.build_problem(inputs, params, nominal, poses=poses,
                                      correct_dilution=False)
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
    """Per-edge laser-vs-odometry disagreement d and its covariance in two parts, so a
    noise model can rescale the wheels' share without recomputing anything else."""

    d: np.ndarray  # (m, 3) laser frame
    wheel_cov: np.ndarray  # (m, 3, 3) J Σ_w Jᵀ, the wheels' slip (what noise effects scale)
    fixed_cov: np.ndarray  # (m, 3, 3) the scan match's share and the odometry's other parts

    def nll(self, wheel_scale=1.0):
        """Per-edge NLL with the wheels' share multiplied by wheel_scale ((m,) or a
        number)."""
        scale = np.reshape(np.asarray(wheel_scale, float), (-1, 1, 1))
        cov = self.wheel_cov * scale + self.fixed_cov
        sq = np.einsum("mi,mij,mj->m", self.d, np.linalg.inv(cov), self.d)
        return 0.5 * (graph_mod.LASER_KERNEL.rho(sq) + np.linalg.slogdet(cov)[1])


@dataclass
class OdometryCovariance:
    """The odometry edges' covariance and the part of it a noise effect rescales.

    A noise effect is a floor or a speed at which the wheels slip more: it scales the
    wheel noise (params.wheel_noise), not the sideways slip that keeps the edges full rank,
    the encoders' quantisation or the interpolation between slow samples. Scaling the
    whole covariance diluted the effect into those parts (docs/decisions/diagnose.md)."""

    total: np.ndarray  # (m_o, 3, 3) graph.odometry_covariance
    wheels: np.ndarray  # (m_o, 3, 3) its wheel-noise part

    @classmethod
    def of(cls, inputs, params, k):
        return cls(graph_mod.odometry_covariance(inputs, params, k),
                   kinematics.motion_covariance(inputs.odo_dphi, k, params.wheel_noise,
                                                floor=0.0, parts=inputs.odo_parts))


def disagreement(fit: Fit, effects, inputs, edges: Edges, odo_cov: OdometryCovariance) -> Disagreement:
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
    odometry_scale = fit.scales.get("odometry", 1.0)
    cov_w = odo_cov.wheels[oi] * odometry_scale
    cov_rest = (odo_cov.total[oi] - odo_cov.wheels[oi]) * odometry_scale
    cov_z = np.linalg.inv(inputs.laser_info[li]) * fit.scales.get("laser", 1.0)
    return Disagreement(d, j_m @ cov_w @ np.swapaxes(j_m, 1, 2),
                        j_m @ cov_rest @ np.swapaxes(j_m, 1, 2)
                        + d_z @ cov_z @ np.swapaxes(d_z, 1, 2))


def edge_nll(fit: Fit, effects, inputs, edges: Edges, odo_cov, noise=()):
    """Per-edge negative log-likelihood of the laser-vs-odometry disagreement, the
    wheels' noise scaled by the fitted noise effects `noise`."""
    dis = disagreement(fit, effects, inputs, edges, odo_cov)
    return dis.nll(combined_scale(noise, edges.pose_i, edges.pose_j))


def _fit_noise(noise, fit: Fit, mech, inputs, edges: Edges, odo_cov, rounds: int):
    """Fit the noise effects to the disagreement of `edges` under `fit` (`rounds` of
    coordinate descent, noise_model.fit_noise); the NLL before and after (per edge)."""
    dis = disagreement(fit, mech, inputs, edges, odo_cov)
    fit_noise(noise, edges.pose_i, edges.pose_j, dis.nll, rounds)
    return dis.nll(), dis.nll(combined_scale(noise, edges.pose_i, edges.pose_j))


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
    odo_cov: OdometryCovariance
    base: Fit
    folds: list  # contiguous time blocks: mean effects
    spread_folds: list  # blocks spread over the run: noise effects
    regs: dict = field(default_factory=dict)
    edge_reg: np.ndarray = None
    config: DiagnoseConfig = field(default_factory=DiagnoseConfig)
    whole: dict = field(default_factory=dict)
    heldout: dict = field(default_factory=dict)

    def effects(self, names):
        return [LIBRARY[n](self.data, self.config) for n in names]

    def split_effects(self, names):
        """(mechanical effects, noise effects), fresh instances of `names`."""
        effects = self.effects(names)
        return ([e for e in effects if e.kind != "noise"], [e for e in effects if e.kind == "noise"])

    def fit_whole(self, names):
        """(Fit of the mechanical effects, fitted noise effects, whole-run cost)."""
        key = tuple(names)
        if key not in self.whole:
            mech, noise = self.split_effects(names)
            fit = _fit_effects(self.base, mech) if mech else self.base
            cost = fit.cost
            if noise:  # 2·ΔNLL: the same scale as the graph's χ²-type cost
                before, after = _fit_noise(noise, fit, mech, self.inputs, self.edges, self.odo_cov,
                                           self.config.noise.fit_rounds)
                cost -= 2.0 * float(np.sum(before - after))
            self.whole[key] = (fit, noise, cost)
        return self.whole[key]

    def odometry_residuals(self, names):
        """(Fit, {odometry component: whitened residuals}) of the mechanical effects of
        `names` fitted on the whole run."""
        fit = self.fit_whole(names)[0]
        residuals = _component_residuals(fit.problem, fit.values, self.edges)
        return fit, {c: r for c, r in residuals.items() if c.startswith("odometry.")}

    def shares(self, names) -> dict:
        """regressor -> fraction of the odometry residuals' structure it explains, left by
        the mechanical effects of `names` fitted on the whole run ({} if none is left)."""
        fit, residuals = self.odometry_residuals(names)
        motion = kinematics.forward(self.inputs.odo_dphi, fit.values["odometry"][0])
        return regressor_shares(residuals, self.regs, self.edge_reg, motion,
                                self.config.structure)[0]

    def mean_structure(self, names) -> list:
        """Significant dependence of the odometry residuals' mean on a regressor
        (autocorrelation aside) left by the mechanical effects of `names`, fitted on the
        whole run. Only the odometry's: the noise effects scale the odometry's covariance,
        and the laser residuals depend on the change of wheel speed / the angular
        acceleration on some routes with no effect at all (the scan matcher's, not the
        wheels'; docs/decisions/diagnose.md)."""
        residuals = self.odometry_residuals(names)[1]
        tests = residual_tests(residuals, self.regs, {c: self.edge_reg for c in residuals},
                               self.config.structure)
        return [t for t in significant(tests, self.config.structure) if t["regressor"] != "lag"]

    def heldout_nll(self, names, spread=False):
        """Per-edge NLL of every held-out block, concatenated in fold order, on the
        contiguous folds or (spread) the spread ones."""
        key = (tuple(names), spread)
        if key not in self.heldout:
            per_fold = []
            for fold in self.spread_folds if spread else self.folds:
                mech, noise = self.split_effects(names)  # noise effects are fitted per fold
                fit = _fit_effects(fold.train, mech) if mech else fold.train
                if noise:
                    _fit_noise(noise, fit, mech, self.inputs, fold.train_edges, self.odo_cov,
                               self.config.noise.fit_rounds)
                per_fold.append(edge_nll(fit, mech, self.inputs, fold.test, self.odo_cov, noise))
            self.heldout[key] = np.concatenate(per_fold)
        return self.heldout[key]


def _time_block_folds(inputs, edges, base, params, nominal, observability, folds,
                      blocks_per_fold=1) -> list:
    """Folds of `blocks_per_fold` time blocks each, spread over the run (fold k holds
    blocks k, k + folds, ...; one block: contiguous folds)."""
    blocks = np.array_split(np.arange(inputs.size), folds * blocks_per_fold)
    out = []
    for k in range(folds):
        held = np.zeros(inputs.size, bool)
        held[np.concatenate(blocks[k::folds])] = True
        test = held[edges.pose_j] & held[edges.pose_i]
        if not test.any():
            continue
        train = _fit_base(_subset(inputs, ~held), params, nominal, observability,
                          poses=base.values["poses"])
        out.append(_Fold(_edges_where(edges, test), _edges_where(edges, ~held[edges.pose_j]
                                                                  & ~held[edges.pose_i]), train))
    return out


def _standard_error(x) -> float:
    return float(x.std(ddof=1) / np.sqrt(len(x))) if len(x) > 1 else float("inf")


def _evaluate(models: _Models, selected, name, n_edges) -> dict:
    """Evidence for adding effect `name` to the `selected` ones: held-out gain, likelihood
    ratio against the BIC penalty, and whether the recording can tell it apart from them
    (identifiability). It passes only with all three."""
    fit, noise, cost = models.fit_whole(selected + [name])
    cost_before = models.fit_whole(selected)[2]
    candidate = next((e for e in noise if e.name == name), None) or models.effects([name])[0]
    spread = candidate.kind == "noise"
    gain = models.heldout_nll(selected, spread) - models.heldout_nll(selected + [name], spread)
    # A region placed by the walls is tested by its search's best rectangle
    # (FloorNoise.search_deficit): the statistic the penalty was set on.
    lr = float(cost_before - cost) + 2.0 * candidate.search_deficit
    bic = candidate.dim * np.log(n_edges)
    # An effect found by a search (a region's place) overfits its in-sample likelihood
    # ratio by more than a count of parameters can say for every run; its place is
    # searched again on every fold's training edges, so its held-out likelihood ratio
    # must clear the penalty of its one fitted ratio too.
    heldout_lr = 2.0 * float(gain.sum())
    heldout_penalty = float(np.log(n_edges)) if candidate.searched else None
    value, sigma, params = _effect_value(models, fit, noise, name)
    ident_config = models.config.identifiability
    ident = identifiability.check(candidate, models.effects(selected), fit, noise, models.edges,
                                  ident_config)
    # The held-out gain must exceed its own standard error, not just 0: a clock offset of
    # a few σ of noise otherwise passes on clean recordings (docs/decisions/diagnose.md).
    evidence_passes = bool(gain.mean() > _standard_error(gain) and lr > bic
                           and (heldout_penalty is None or heldout_lr > heldout_penalty))
    # A variance model fitted over an unexplained mean takes the mean's squared error for
    # noise (a radius growing with speed passes for noise growing with the turn rate), so
    # noise effects wait until no mean structure is left.
    mechanical = [n for n in selected if LIBRARY[n].kind != "noise"]
    stand_in = _stand_in(models, mechanical, candidate)
    blocked = []
    if candidate.kind == "noise":
        blocked = [f"{t['component']} vs {t['regressor']}"
                   for t in models.mean_structure(mechanical)]
    return {"name": name, "value": value, "sigma": sigma, "params": params,
            "added_to": list(selected), "gain": gain, "lr": lr, "bic": float(bic),
            "heldout_lr": heldout_lr, "heldout_penalty": heldout_penalty,
            "heldout_error": float(np.mean(models.heldout_nll(selected + [name], spread))),
            "heldout_error_base": float(np.mean(models.heldout_nll([], spread))),
            "heldout_folds": "spread" if spread else "contiguous",
            "identifiability": ident, "evidence_passes": evidence_passes,
            "blocked_by_mean_structure": blocked, "stand_in_for": stand_in,
            "describe": next((e.describe() for e in noise if e.name == name), {}),
            "passes": (evidence_passes and identifiability.separable(ident, ident_config)
                       and not blocked and stand_in is None)}


def _stand_in(models: _Models, mechanical, candidate):
    """The regressor a mean effect would only stand in for, or None: one outside its
    signature that explains more of the odometry's structure (left by the selected
    mechanical effects) than its signature does. A wheel radius growing with speed, on a
    drive whose speed changes over the run, looks like a radius drifting in time, and
    radius_drift passes every other test there while the speed explains more than the
    time does (docs/decisions/diagnose.md)."""
    if not candidate.signature:
        return None
    shares = models.shares(mechanical)
    if not shares:
        return None
    own = max(shares.get(name, 0.0) for name in candidate.signature)
    best = max(shares, key=shares.get)
    if best in candidate.signature or shares[best] <= own:
        return None
    return {"regressor": best, "fraction_explained": float(shares[best]),
            "signature_fraction": float(own)}


def _effect_value(models: _Models, fit: Fit, noise, name):
    """(reported value, its σ, the parameter vector) of effect `name` in a fit."""
    fitted = next((e for e in noise if e.name == name), None)
    if fitted is not None:
        return fitted.value(), fitted.value_sigma(), None
    effect = models.effects([name])[0]
    p = fit.values[name][0]
    cov = marginal_covariance(fit.problem, fit.values, [name])
    pick = int(np.argmax(np.abs(p))) if effect.dim > 1 else 0
    return effect.value(p), float(np.sqrt(cov[pick, pick])), p.tolist()


def _stepwise_selection(models: _Models, names, n_edges, say):
    """Stepwise selection. Each round, every remaining effect is fitted on top of the ones
    selected so far, and one of those that pass (held-out gain > its standard error, likelihood ratio >
    BIC penalty, determined together with the selected ones) joins: the simplest of those
    whose held-out error is within one standard error of the best's (the one-standard-
    error rule). Then each earlier selected effect is tried on top of the others, and
    leaves for good if it no longer passes. Trying effects on top of the selected ones,
    not only against the base model, lets an effect whose signature is buried under a
    larger one show, and keeps one that only re-explains a selected one out.

    When none passes, an effect that has the evidence but cannot be told apart from
    selected ones (identifiability) may replace them, if the model with it instead has
    the lower held-out error: a clock offset selected first gives way to a sweep's
    delay with its turn-rate shift, never both. Every pair of a candidate and a selected
    effect that the recording cannot separate is returned, whether or not the candidate
    had the evidence.

    Returns the selected names, per effect the evidence of the last time it was tried,
    and the pairs the recording cannot separate.
    """
    max_correlation = models.config.identifiability.max_correlation
    selected, evidence, pairs = [], {}, []
    remaining = list(names)
    while remaining:
        say("trying " + ", ".join(remaining) + (" on top of " + ", ".join(selected)
                                                 if selected else ""))
        round_ = {n: _evaluate(models, selected, n, n_edges) for n in remaining}
        evidence.update(round_)
        pairs += [{"effects": sorted([n, other]),
                   "correlation": round_[n]["identifiability"]["correlations"][other]}
                  for n in remaining for other in _entangled(round_[n], max_correlation)]
        passing = [n for n in remaining if round_[n]["passes"]]
        if passing:
            chosen, near = _simplest_near_best(models, selected, passing, round_)
            # What else the data fit about as well: the choice among them is the simplest,
            # not what the recording showed, and the report says so.
            evidence[chosen] = {**round_[chosen], "alternatives": [n for n in near if n != chosen]}
            selected.append(chosen)
            remaining.remove(chosen)
        else:
            swap = _best_swap(models, selected, remaining, round_, n_edges)
            if swap is None:
                break
            chosen, replaced, ev = swap
            say(f"{chosen} replaces {', '.join(replaced)}: not separable, lower held-out error")
            evidence[chosen] = ev
            selected = [n for n in selected if n not in replaced] + [chosen]
            remaining.remove(chosen)
        for earlier in selected[:-1]:
            others = [n for n in selected if n != earlier]
            again = _evaluate(models, others, earlier, n_edges)
            if not again["passes"]:
                say(f"dropping {earlier}: no longer adds to " + ", ".join(others))
                evidence[earlier] = again
                selected.remove(earlier)
    return selected, evidence, _unique_pairs(pairs, selected)


def _entangled(ev, max_correlation) -> list:
    """The selected effects an evaluated candidate cannot be told apart from."""
    return [n for n, c in ev["identifiability"]["correlations"].items() if c > max_correlation]


def _best_swap(models: _Models, selected, remaining, round_, n_edges):
    """(candidate, the selected effects it replaces, its evidence) of the best replacement
    among candidates that have the evidence but not the identifiability, or None."""
    best = None
    for name in remaining:
        ev = round_[name]
        tangled = _entangled(ev, models.config.identifiability.max_correlation)
        if not ev["evidence_passes"] or not tangled:
            continue
        spread = LIBRARY[name].kind == "noise"
        current = float(np.mean(models.heldout_nll(selected, spread)))
        others = [n for n in selected if n not in tangled]
        again = _evaluate(models, others, name, n_edges)
        error = float(np.mean(models.heldout_nll(others + [name], spread)))
        if again["passes"] and error < current and (best is None or error < best[3]):
            best = (name, tangled, again, error)
    return None if best is None else best[:3]


def _unique_pairs(pairs, selected) -> list:
    out = {}
    for p in pairs:
        key = tuple(p["effects"])
        if key not in out or p["correlation"] > out[key]["correlation"]:
            out[key] = {**p, "selected": [n for n in key if n in selected]}
    return list(out.values())


def _simplest_near_best(models: _Models, selected, passing, round_):
    """(chosen, the candidates within one standard error of the best): mean effects before
    noise effects (a variance model over a mean misfit takes the misfit for noise, and the
    two kinds are judged on different folds), then the simplest within one standard error
    of the best."""
    passing = [n for n in passing if LIBRARY[n].kind != "noise"] or passing
    spread = LIBRARY[passing[0]].kind == "noise"
    best = max(passing, key=lambda n: round_[n]["gain"].mean())
    best_nll = models.heldout_nll(selected + [best], spread)

    def near(name):
        worse = models.heldout_nll(selected + [name], spread) - best_nll
        return worse.mean() <= worse.std(ddof=1) / np.sqrt(len(worse))

    close = [n for n in passing if near(n)]
    return min(close, key=lambda n: (models.effects([n])[0].dim, -round_[n]["gain"].mean())), close


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
    config: DiagnoseConfig = field(repr=False, default_factory=DiagnoseConfig)  # what it ran with


def _effect_json(ev: dict, selected_names) -> dict:
    gain = ev["gain"]
    selected = ev["name"] in selected_names
    # What fit about as well as a selected effect, and was not selected itself.
    alternatives = [a for a in ev.get("alternatives", []) if a not in selected_names] if selected else []
    return {
        "name": ev["name"], "selected": selected, "value": ev["value"], "sigma": ev["sigma"],
        "evidence": {
            "heldout_error": ev["heldout_error"], "heldout_error_base": ev["heldout_error_base"],
            "heldout_folds": ev["heldout_folds"],
            "heldout_gain_per_edge": float(gain.mean()),
            "heldout_gain_stderr": _standard_error(gain),
            "likelihood_ratio": ev["lr"], "bic_penalty": ev["bic"],
            "heldout_likelihood_ratio": ev["heldout_lr"],
            **({"heldout_penalty": ev["heldout_penalty"]}
               if ev["heldout_penalty"] is not None else {}),
            "added_to": ev["added_to"],
            "units": LIBRARY[ev["name"]].units,
            "identifiability": ev["identifiability"],
            **({"blocked_by_mean_structure": ev["blocked_by_mean_structure"]}
               if ev["blocked_by_mean_structure"] else {}),
            **({"stand_in_for": ev["stand_in_for"]} if ev["stand_in_for"] else {}),
            **({"alternatives": alternatives} if alternatives else {}),
            **({"params": ev["params"]} if ev["params"] is not None else {}),
        },
        **ev["describe"],
    }


def _extended_fit(models: _Models, selected):
    """The selected effects fitted together (variance components re-estimated), with the
    final value and σ of each."""
    mech, _ = models.split_effects(selected)
    ext = _fit_effects(models.base, mech, variance_components=True) if mech else models.base
    noise = models.fit_whole(selected)[1]
    final = {n: _effect_value(models, ext, noise, n) for n in selected}
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
    nominal = np.array([getattr(params, k) for k in CALIBRATION_KEYS])
    data = EffectData.from_keyframes(keyframes, inputs.stamps, positions=base.values["poses"][:, :2])
    data.walls = WallMap.from_keyframes(keyframes, inputs.stamps, base.values["poses"],
                                        base.values["laser"][0], config.walls)
    wheel_angles = np.array([kf.wheel_angles for kf in merged], float).reshape(-1, 2)
    edges = paired_edges(inputs)
    odo_cov = OdometryCovariance.of(inputs, params, nominal[:3])
    regs = regressors(inputs, data, wheel_angles, base.values["odometry"][0], base.values["poses"])
    odo_pos = {int(a): n for n, a in enumerate(inputs.odo_from)}
    edge_reg = np.array([odo_pos[int(a)] for a in edges.pose_i], int)
    before = _component_residuals(problem, base.values, edges)
    edge_of = {c: edge_reg for c in before}
    tests_before = residual_tests(before, regs, edge_of, config.structure)

    say(f"{selection.folds}-fold time-block cross-validation ({selection.noise_folds} spread "
        "folds for noise effects)")
    fold_args = (inputs, edges, base, params, nominal, base_result.observability)
    models = _Models(data, inputs, edges, odo_cov, base, _time_block_folds(*fold_args, selection.folds),
                     _time_block_folds(*fold_args, selection.noise_folds,
                                       blocks_per_fold=selection.noise_fold_blocks),
                     regs, edge_reg, config)
    n_edges = len(inputs.odo_from) + len(inputs.laser_from)
    selected, evidence, pairs = _stepwise_selection(models, names, n_edges, say)
    base_error = float(np.mean(models.heldout_nll([])))
    ext_error = float(np.mean(models.heldout_nll(selected)))

    say("refitting with the selected effects: " + (", ".join(selected) or "none"))
    ext, final = _extended_fit(models, selected)
    effects_json = []
    for name in names:
        e = _effect_json(evidence[name], selected)
        if name in final:
            e["value"], e["sigma"] = final[name][:2]
        effects_json.append(e)
    after = _component_residuals(ext.problem, ext.values, edges)
    tests_after = residual_tests(after, regs, edge_of, config.structure)
    motion = kinematics.forward(inputs.odo_dphi, ext.values["odometry"][0])
    shift = identifiability.calibration_shift(base, ext, CALIBRATION_KEYS) if selected else {}
    warnings = [f"adding {', '.join(selected)} moved {k} by {z:+.1f} σ (of the extended model)"
                for k, z in shift.items() if abs(z) > config.identifiability.max_shift_sigma]
    warnings += [f"{p['effects'][0]} and {p['effects'][1]} cannot be told apart on this "
                 f"recording (correlation {p['correlation']:.2f}); selected: "
                 f"{', '.join(p['selected']) or 'neither'}" for p in pairs]

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
        "error_metric": ERROR_METRIC.format(folds=selection.folds, noise_folds=selection.noise_folds,
                                             spread=selection.noise_fold_blocks,
                                             c=graph_mod.LASER_KERNEL.c),
        "effects": effects_json,
        "unexplained": [{k: t[k] for k in ("component", "regressor", "strength")}
                        for t in significant(tests_after, config.structure)],
        # The regressors that explain most of what is left (over the structured
        # components), with the fraction each explains.
        "unexplained_cause": name_structure(
            {c: r for c, r in after.items() if c.startswith("odometry.")}, regs, edge_reg,
            motion, config.structure),
        "not_separable": pairs,
        "calibration_shift_sigma": shift,
        "warnings": warnings,
    }
    return Diagnosis(report, before, after, regs, edge_of, tests_before, tests_after, config)


# --- figures ------------------------------------------------------------------------------


def write_diagnosis_report(out_dir, diagnosis: Diagnosis, per_figure: int = 6) -> list:
    """PNG per residual component: the residual against its strongest regressors, before
    (base model) and after (extended model) on the same axes, clipped as the diagnosis's
    tests clip them (its config)."""
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
            # A group of columns is drawn against its least-squares combination.
            x = fitted_values(diagnosis.regressors[t["regressor"]][idx],
                              diagnosis.residuals_before[comp], diagnosis.config.structure)
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
