"""The evidence for adding one effect to those already selected: its held-out gain, its
likelihood ratio against the BIC penalty (and, for an effect found by a search, its
held-out likelihood ratio against ln(edges)), whether the recording can tell it apart
from them, and whether it would only stand in for another cause.
"""
from __future__ import annotations

import numpy as np

from sclam_ros.core.covariance import marginal_covariance
from sclam_ros.diagnosis import identifiability
from sclam_ros.diagnosis.cross_validation import Models
from sclam_ros.diagnosis.effects import LIBRARY
from sclam_ros.diagnosis.fitting import Fit


def standard_error(x) -> float:
    return float(x.std(ddof=1) / np.sqrt(len(x))) if len(x) > 1 else float("inf")


def evaluate(models: Models, selected, name, n_edges) -> dict:
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
    value, sigma, params = effect_value(models, fit, noise, name)
    ident_config = models.config.identifiability
    ident = identifiability.check(candidate, models.effects(selected), fit, noise, models.edges,
                                  ident_config)
    # The held-out gain must exceed its own standard error, not just 0: a clock offset of
    # a few σ of noise otherwise passes on clean recordings (docs/decisions/diagnose.md).
    evidence_passes = bool(gain.mean() > standard_error(gain) and lr > bic
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


def _stand_in(models: Models, mechanical, candidate):
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


def effect_value(models: Models, fit: Fit, noise, name):
    """(reported value, its σ, the parameter vector) of effect `name` in a fit."""
    fitted = next((e for e in noise if e.name == name), None)
    if fitted is not None:
        return fitted.value(), fitted.value_sigma(), None
    effect = models.effects([name])[0]
    p = fit.values[name][0]
    cov = marginal_covariance(fit.problem, fit.values, [name])
    pick = int(np.argmax(np.abs(p))) if effect.dim > 1 else 0
    return effect.value(p), float(np.sqrt(cov[pick, pick])), p.tolist()
