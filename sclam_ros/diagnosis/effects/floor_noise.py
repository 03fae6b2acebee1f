"""Odometry noise that depends on where the robot drives (carpet, tiles, a threshold).

A noise factor per region of the map. The regions are four cells of equal numbers of
edges: the edges' fitted mid-points are split at the median of the axis along which the
route spreads more, then each half at the median of the other axis. (Not a grid at the
quantiles of x and y: a route along an L puts almost no edge in two of its cells —
measured: 4, 4, 86, 86 edges on a 90 s simulated run.) Each region's odometry
covariance is multiplied by λ_r / λ_0: λ_r is the maximum-likelihood factor of the
region's laser-vs-odometry disagreements, whose covariance is λ·(odometry part) +
(scan-match part), and λ_0 the same over all edges, so the effect models how regions
differ, never a misfit of the overall odometry scale (which would otherwise pass for a
floor: measured λ_r ≈ 0.5 in both populated regions of a run without any floor effect). (Not the
χ²/dof of the odometry residuals of a joint fit: the poses hand part of every
disagreement to the scan matches, more of it the noisier the odometry, so that ratio is
pulled towards 1 — measured on a simulated floor with twice the slip σ, variance ratio 4:
it gave 2.4.) It changes the noise model, not the mean, so it is not a least-squares
block: it is estimated from the disagreements of a fit and judged by held-out likelihood
like every other effect.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import minimize_scalar

from sclam_ros.diagnosis.effects.base import ModelEffect


class FloorNoise(ModelEffect):
    name = "floor_noise"
    kind = "noise"
    units = "variance ratio (largest / smallest region)"
    doc = "odometry noise scale per map region"
    REGIONS = 4
    dim = REGIONS - 1  # one overall scale is the base model's
    # A region's factor from fewer edges is too uncertain to tell floors apart (from 20
    # edges of 3 components: ±26 % at 1σ for Gaussian disagreements).
    MIN_EDGES = 20
    LOG_RANGE = np.log(100.0)  # factors searched within [1/100, 100]

    def __init__(self, data):
        super().__init__(data)
        self.first_axis = 0
        self.first_split = 0.0
        self.second_splits = np.zeros(2)
        self.scales = np.ones(self.REGIONS)
        self.fitted = np.zeros(self.REGIONS, bool)

    def _midpoints(self, pose_i, pose_j):
        return 0.5 * (self.data.positions[pose_i] + self.data.positions[pose_j])

    def _place_splits(self, mid):
        self.first_axis = int(np.argmax(np.ptp(mid, axis=0)))
        first, second = mid[:, self.first_axis], mid[:, 1 - self.first_axis]
        self.first_split = float(np.median(first))
        upper = first > self.first_split
        self.second_splits = np.array([np.median(second[~upper]) if (~upper).any() else 0.0,
                                       np.median(second[upper]) if upper.any() else 0.0])

    def region(self, pose_i, pose_j):
        """Region index (0..3) of edges, from the mid-point of their two positions."""
        mid = self._midpoints(pose_i, pose_j)
        upper = (mid[:, self.first_axis] > self.first_split).astype(int)
        return 2 * upper + (mid[:, 1 - self.first_axis] > self.second_splits[upper])

    def fit(self, pose_i, pose_j, nll):
        """Per-region factors on the odometry covariance, by maximum likelihood, relative
        to the factor of all edges together.

        nll: per-edge factors (m,) → per-edge negative log-likelihood (m,) of the edges
        (pose_i, pose_j), e.g. diagnose.Disagreement.nll. A region with fewer than
        MIN_EDGES edges keeps the overall factor."""
        self._place_splits(self._midpoints(pose_i, pose_j))
        region = self.region(pose_i, pose_j)
        overall = _ml_factor(nll, np.ones(len(region), bool))
        self.scales = np.ones(self.REGIONS)
        self.fitted = np.array([np.sum(region == r) >= self.MIN_EDGES
                                for r in range(self.REGIONS)])
        for r in np.flatnonzero(self.fitted):
            self.scales[r] = _ml_factor(nll, region == r) / overall
        return self.scales

    def scale_of(self, pose_i, pose_j):
        return self.scales[self.region(pose_i, pose_j)]

    def value(self, p=None):
        """Largest over smallest factor of the regions with enough edges to fit."""
        fitted = self.scales[self.fitted] if self.fitted.any() else self.scales
        return float(np.max(fitted) / max(np.min(fitted), 1e-300))


def _ml_factor(nll, inside) -> float:
    """The factor on the odometry covariance of the `inside` edges minimising their NLL."""
    def region_nll(log_factor):
        factors = np.ones(len(inside))
        factors[inside] = np.exp(log_factor)
        return float(np.sum(nll(factors)[inside]))

    best = minimize_scalar(region_nll, bounds=(-FloorNoise.LOG_RANGE, FloorNoise.LOG_RANGE),
                           method="bounded", options={"xatol": 1e-4})
    return float(np.exp(best.x))
