"""Several noise effects at once: their factors on the wheels' noise multiply.

Each is fitted with the others' factors held, over a few rounds of coordinate descent
(NoiseConfig.fit_rounds: the effects follow different regressors, so a second round
changes little).
"""
from __future__ import annotations

import numpy as np


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
