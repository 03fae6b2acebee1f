"""Can the recording tell an effect apart from those already in the model, and did the
model's calibration move more than its uncertainty allows?

An effect joins the model only if it is determined together with the selected ones
(IdentifiabilityConfig):
- its parameters' posterior σ is at most sigma_ratio of their prior σ (the prior that
  keeps an unexcited effect well-posed; at σ ≈ prior the data say nothing about it; for
  a noise effect with a σ, its log factor's against a log uniform over the factors it
  searches, _noise_sigma_ratio), and
- no correlation between its parameters and a selected effect's exceeds max_correlation.
  For mechanical effects: of the joint marginal covariance in the graph. For noise
  effects: of the log factors they put on the edges (a carpet the robot only crosses
  slowly and a noise that grows with speed cannot both be fitted).
Two effects that pass the held-out test each but fail this together are reported as a
pair the recording cannot separate, instead of both being selected: a clock offset and a
scan-timing delay, one parameter when both are in the model, would otherwise both be
selected with σ equal to their priors (docs/decisions/diagnose.md).
"""
from __future__ import annotations

import numpy as np

from sclam_ros.core.covariance import marginal_covariance
from sclam_ros.diagnosis.config import IdentifiabilityConfig


def _log_scales(effect, edges):
    return np.log(np.maximum(effect.scale_of(edges.pose_i, edges.pose_j), 1e-300))


def _noise_sigma_ratio(effect):
    """σ of a fitted noise effect's log factor over its prior's, or None for an effect that
    states no σ. The prior: the log uniform over the factors the effect searches (its
    `levels`; floor_noise: FloorNoiseConfig.levels). A rectangle of a few edges otherwise
    joins with a ratio the recording hardly determines (docs/decisions/diagnose.md)."""
    sigma = effect.value_sigma()
    if sigma is None or not effect.value() > 0:
        return None
    prior = np.ptp(effect.levels) / np.sqrt(12.0)
    return float(sigma / effect.value() / prior)


def check(candidate, selected, fit, noise, edges, config: IdentifiabilityConfig) -> dict:
    """{"determined", "sigma_ratio", "correlations": {other: |ρ|}} for the candidate
    effect (an instance) fitted together with the `selected` instances in `fit` (mechanical
    effects) and `noise` (the fitted noise effects)."""
    correlations = {}
    if candidate.kind == "noise":
        mine = _log_scales(candidate, edges)
        for other in noise:
            if other is candidate or other.name == candidate.name:
                continue
            theirs = _log_scales(other, edges)
            if np.std(mine) > 0 and np.std(theirs) > 0:
                correlations[other.name] = float(abs(np.corrcoef(mine, theirs)[0, 1]))
        ratio = _noise_sigma_ratio(candidate)
        return {"determined": ratio is None or ratio <= config.sigma_ratio, "sigma_ratio": ratio,
                "correlations": correlations}
    blocks = [e.name for e in selected if e.kind != "noise" and e.name != candidate.name]
    cov = marginal_covariance(fit.problem, fit.values, [candidate.name] + blocks)
    sigma = np.sqrt(np.maximum(np.diag(cov), 0.0))
    d = candidate.dim
    ratio = float(np.max(sigma[:d]) / candidate.prior_sigma)
    corr = cov / np.maximum(np.outer(sigma, sigma), 1e-300)
    start = d
    for e in selected:
        if e.name not in blocks:
            continue
        dim = type(e).dim
        correlations[e.name] = float(np.max(np.abs(corr[:d, start:start + dim])))
        start += dim
    return {"determined": ratio <= config.sigma_ratio, "sigma_ratio": ratio,
            "correlations": correlations}


def separable(result: dict, config: IdentifiabilityConfig) -> bool:
    return result["determined"] and all(c <= config.max_correlation
                                        for c in result["correlations"].values())


def calibration_shift(base_fit, extended_fit, keys) -> dict:
    """Per calibration parameter: (extended − base) / σ of the extended model."""
    blocks = ["odometry", "laser"]
    cov = marginal_covariance(extended_fit.problem, extended_fit.values, blocks)
    sigma = np.sqrt(np.maximum(np.diag(cov), 1e-300))
    before = np.concatenate([base_fit.values[b][0] for b in blocks])
    after = np.concatenate([extended_fit.values[b][0] for b in blocks])
    return {k: float(v) for k, v in zip(keys, (after - before) / sigma)}
