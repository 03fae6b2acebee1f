"""Several noise effects at once: their factors on the wheels' noise multiply.

Each is fitted with the others' factors held, over a few rounds of coordinate descent
(NoiseConfig.fit_rounds: the effects follow different regressors, so a second round
changes little).
"""
from __future__ import annotations

import numpy as np

from sclam_ros.diagnosis.effects.noise_fit import ml_factor


def fit_noise(effects, pose_i, pose_j, nll, rounds: int) -> None:
    """Fit `effects` (kind "noise") to the edges (pose_i, pose_j); nll: per-edge factors
    (m,) → per-edge NLL (m,); `rounds` of coordinate descent when there are several."""
    for _ in range(rounds if len(effects) > 1 else 1):
        for e in effects:
            others = combined_scale([o for o in effects if o is not e], pose_i, pose_j)
            e.fit(pose_i, pose_j, lambda factors, others=others: nll(factors * others))


def combined_scale(effects, pose_i, pose_j):
    """The product of the effects' factors per edge ((m,) or 1.0 with no effect)."""
    scale = np.ones(len(pose_i))
    for e in effects:
        scale = scale * e.scale_of(pose_i, pose_j)
    return scale


def level_profiled_nll(nll, scale, log_range: float) -> np.ndarray:
    """Per-edge NLL (m,) with the wheels' noise at the effects' factors `scale` ((m,)), its
    overall level at the one common factor that fits best (within exp(±log_range), as
    every noise fit searches).

    What a noise effect's likelihood ratio compares: the base model's level is the stated
    wheel noise at its variance-component scale, which the disagreements may not bear out
    (exact encoders: hundreds of nats below it); a fitted effect must not take that as its
    evidence. Both models get their level by the same fit, and only the factors' shape
    (divided by their geometric mean) differs: factors the same on every edge (a variance
    ratio of one) give the base model's NLL exactly."""
    log_scale = np.log(np.asarray(scale, float))
    if np.ptp(log_scale) == 0.0:
        shape = np.ones(len(log_scale))
    else:
        shape = np.exp(log_scale - log_scale.mean())
    # Each edge's factor within the range the fits search (as NoiseVsMotion's total clips
    # them): at a level pinned to the bound, a slope must not reach below it on half the
    # edges and count the level's gain as its own.
    bound = np.exp(log_range)

    def at(factors):
        return nll(np.clip(factors * shape, 1.0 / bound, bound))

    level = ml_factor(at, np.ones(len(shape), bool), log_range)
    return at(level)
