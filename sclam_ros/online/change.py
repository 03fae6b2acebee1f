"""The radii's change model: fading memory for slow drift, change points for steps.

The marginalised data of the online window is a sequence of Gaussians on the calibration
(r_l, r_r, b, l_x, l_y, l_yaw; core/marginal.py), oldest first, the last one being the
pose window's own information. The wheel base and the laser pose are the same in all of
them; the radii are piecewise constant (a load put on or taken off, a tyre losing air at
once) and drift slowly in between (wear, a slow leak).

- Drift: as data ages by `m` metres, the information it carries about the radii *given*
  (b, l) is scaled by exp(−m / L): what it says about (b, l) is kept in full (fade_radii).
  L = window_distance, so the radii come from about the last window_distance metres, as
  in a sliding window, while the wheel base and the laser keep all their information:
  the radii of different times are tied together, not integrated out chunk by chunk.
- Steps: a generalised likelihood-ratio test (change_point) for "the radii changed
  between unit k and k+1" against "no change", at every boundary, maximised over k. With a
  change found, everything before it is one segment whose radii are integrated out jointly
  (its (b, l) information kept for good); the data after it, marginalised chunks included,
  stays a prior on the new radii. The change time is where the test puts it, not where it
  was detected, so data between a change and its detection informs the new radii and never
  the old ones.
- Doubt: until a change is acted on, the radii published are the no-change model's; their
  covariance weighs in the change model at the best boundary by the test's posterior odds
  (radii_covariance_with_change), so a change being detected widens σ instead of leaving
  the old radii with their old certainty.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np

from sclam_ros.core.marginal import NOT_RADII, RADII, Gaussian


def fade_radii(gaussian: Gaussian, factor: float) -> Gaussian:
    """The Gaussian with the information on the radii given (b, l) scaled by `factor`
    (0: the radii integrated out, Gaussian.without_radii; 1: unchanged); the marginal on
    (b, l) is unchanged whatever the factor.

    p(r, s) = p(r | s) p(s): the conditional's information [[Λrr, Λrs], [Λsr, Λsr Λrr⁺ Λrs]]
    and vector [ηr, Λsr Λrr⁺ ηr] are scaled, the marginal's (Λss − Λsr Λrr⁺ Λrs,
    ηs − Λsr Λrr⁺ ηr) kept."""
    if factor >= 1.0:
        return gaussian
    info, eta = gaussian.information, gaussian.eta
    l_rr = info[np.ix_(RADII, RADII)]
    l_sr = info[np.ix_(NOT_RADII, RADII)]
    coupling = l_sr @ np.linalg.pinv(l_rr, hermitian=True)  # Λsr Λrr⁺
    out = Gaussian(info.copy(), eta.copy())
    out.information[np.ix_(RADII, RADII)] *= factor
    out.information[np.ix_(RADII, NOT_RADII)] *= factor
    out.information[np.ix_(NOT_RADII, RADII)] *= factor
    out.information[np.ix_(NOT_RADII, NOT_RADII)] -= (1.0 - factor) * coupling @ l_sr.T
    out.eta[RADII] *= factor
    out.eta[NOT_RADII] -= (1.0 - factor) * coupling @ eta[RADII]
    return out


def faded_sums(gaussians, metres, fading_length: float, start: Gaussian = None) -> list:
    """The running sums of `gaussians` (oldest first, each `metres` long), the older ones'
    radii faded by the metres driven after them: [start, start+g0, ...]; `start`: an older
    Gaussian to continue from."""
    sums = [start if start is not None else Gaussian()]
    for gaussian, length in zip(gaussians, metres):
        sums.append(fade_radii(sums[-1], float(np.exp(-length / fading_length))) + gaussian)
    return sums


def faded_sum(gaussians, metres, fading_length: float, start: Gaussian = None) -> Gaussian:
    """The last of faded_sums: all of `gaussians` after `start`, radii faded by age."""
    return faded_sums(gaussians, metres, fading_length, start)[-1]


@dataclass(frozen=True)
class ChangePoint:
    statistic: float  # the likelihood ratio 2 (ℓ_change − ℓ_none), maximised over boundaries
    boundary: int  # the best boundary: the change lies between unit boundary-1 and boundary
    # At the best boundary (None without one): the radii after it under the change model
    # less the radii of the model without a change (2,), and the two models' covariances
    # of those radii (2, 2), under the units' noise model.
    shift: Optional[np.ndarray] = None
    after_covariance: Optional[np.ndarray] = None
    none_covariance: Optional[np.ndarray] = None


def _max_log_likelihood(information, eta, scale) -> float:
    """max_x (ηᵀx − ½ xᵀΛx) = ½ ηᵀΛ⁻¹η, in variables whitened by `scale`."""
    info = information * np.outer(scale, scale)
    vec = eta * scale
    return 0.5 * float(vec @ np.linalg.lstsq(info, vec, rcond=1e-12)[0])


def _posterior(information, eta, scale):
    """(mean, covariance) of the Gaussian (Λ, η), solved in variables whitened by `scale`."""
    outer = np.outer(scale, scale)
    covariance = np.linalg.pinv(information * outer, rcond=1e-12, hermitian=True) * outer
    return covariance @ eta, covariance


def _change_model(a: Gaussian, b: Gaussian):
    """Information and vector of "radii r_a in `a`, r_b in `b`, (b, l) shared": the
    8-dimensional model (r_a, b, l, r_b) = columns (RADII, NOT_RADII, 6, 7)."""
    info = np.zeros((8, 8))
    eta = np.zeros(8)
    info[:6, :6] = a.information
    eta[:6] = a.eta
    idx = [6, 7, *NOT_RADII]
    src = [*RADII, *NOT_RADII]
    info[np.ix_(idx, idx)] += b.information[np.ix_(src, src)]
    eta[idx] += b.eta[src]
    return info, eta


def change_point(units, metres, fading_length, reference: Gaussian, scale,
                 first_boundary: int = 1) -> ChangePoint:
    """The likelihood-ratio test for one change of the radii among `units`.

    `units`: Gaussians oldest first (each also carrying its share of any weak prior that
    makes the sums proper); `reference`: what precedes them (faded in as the oldest data);
    `scale`: (6,) a σ per parameter to whiten by (the prior's). For a boundary k the
    model "radii r_a before, r_b from unit k on, (b, l) shared" is an 8-dimensional
    Gaussian; its best log-likelihood against the shared model's is a χ² with 2 degrees of
    freedom at a boundary fixed in advance (larger when maximised over boundaries)."""
    before = faded_sums(units, metres, fading_length, reference)
    after = [Gaussian()] * (len(units) + 1)
    for k in range(len(units) - 1, -1, -1):
        after[k] = after[k + 1] + units[k]
    scale = np.asarray(scale, float)
    scale8 = np.concatenate([scale, scale[RADII]])
    best = ChangePoint(0.0, -1)
    for k in range(max(first_boundary, 1), len(units)):
        # The same pieces under both models: only whether they share the radii differs.
        a, b = before[k], after[k]
        none = _max_log_likelihood((a + b).information, (a + b).eta, scale)
        statistic = 2.0 * (_max_log_likelihood(*_change_model(a, b), scale8) - none)
        if statistic > best.statistic:
            best = ChangePoint(statistic, k)
    if best.boundary < 0:
        return best
    a, b = before[best.boundary], after[best.boundary]
    none_mean, none_cov = _posterior((a + b).information, (a + b).eta, scale)
    change_mean, change_cov = _posterior(*_change_model(a, b), scale8)
    return ChangePoint(best.statistic, best.boundary, change_mean[6:] - none_mean[RADII],
                       change_cov[6:, 6:], none_cov[np.ix_(RADII, RADII)])


def change_weight(statistic: float, threshold: float) -> float:
    """The change model's share of the radii's uncertainty, from the likelihood ratio:
    posterior odds exp(statistic / 2) × prior odds, with the prior odds exp(−threshold / 2)
    that make the statistic at which a change is declared even odds."""
    return float(1.0 / (1.0 + np.exp(-0.5 * (statistic - threshold))))


def radii_covariance_with_change(radii_cov, found: ChangePoint, weight: float,
                                 variance_factor: float = 1.0) -> np.ndarray:
    """The radii's covariance (2, 2) about the no-change estimate, with the possibility of a
    change at the best boundary weighed in: the mixture w₀ Σ₀ + w₁ (Σ₁ + d dᵀ) of the two
    models (d the shift of the radii, Σ their covariances scaled by `variance_factor`),
    which is `radii_cov` plus w₁ (Σ₁ − Σ₀ + d dᵀ), clipped to positive semidefinite.

    Without it, the estimate published while a load change is being detected is the old
    radii with the old σ, many σ off the new radii
    (docs/decisions/online.md#radii-sigma-during-a-change)."""
    if found.shift is None or not weight > 0.0:
        return radii_cov
    extra = weight * (variance_factor * (found.after_covariance - found.none_covariance)
                      + np.outer(found.shift, found.shift))
    if not np.all(np.isfinite(extra)):  # a degenerate test says nothing: the model's σ stands
        return radii_cov
    eigval, eigvec = np.linalg.eigh(0.5 * (extra + extra.T))
    return radii_cov + (eigvec * np.clip(eigval, 0.0, None)) @ eigvec.T
