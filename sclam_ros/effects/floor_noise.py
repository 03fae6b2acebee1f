"""Odometry noise that depends on where the robot drives (carpet, tiles, a threshold).

A noise scale per region of the map: the fitted positions are split into a grid of
``cells`` × ``cells`` regions at the quantiles of x and y (equal numbers of edges), and the
odometry edges of each region get their own variance factor, estimated from their
whitened residuals (χ²/dof, the variance-component estimate of the region). It changes
the noise model, not the mean, so it is not a least-squares block: it is estimated from
the residuals of a fit and judged by held-out likelihood like every other effect.
"""
from __future__ import annotations

import numpy as np

from .base import ModelEffect


class FloorNoise(ModelEffect):
    name = "floor_noise"
    kind = "noise"
    units = "variance ratio (largest / smallest region)"
    doc = "odometry noise scale per map region"
    cells = 2

    def __init__(self, data):
        super().__init__(data)
        self.edges_x = self.edges_y = None
        self.scales = np.ones(self.cells * self.cells)

    @property
    def dim(self):
        return self.cells * self.cells - 1  # one overall scale is the base model's

    def region(self, poses_i, poses_j):
        """Region index of edges, from the mid-point of their two positions."""
        mid = 0.5 * (self.data.positions[poses_i] + self.data.positions[poses_j])
        ix = np.searchsorted(self.edges_x, mid[:, 0])
        iy = np.searchsorted(self.edges_y, mid[:, 1])
        return ix * self.cells + iy

    def fit(self, pose_i, pose_j, whitened_sq, dof=3):
        """Per-region variance factors relative to the overall one, from training edges'
        squared whitened residual norms."""
        mid = 0.5 * (self.data.positions[pose_i] + self.data.positions[pose_j])
        q = np.linspace(0, 1, self.cells + 1)[1:-1]
        self.edges_x = np.quantile(mid[:, 0], q)
        self.edges_y = np.quantile(mid[:, 1], q)
        region = self.region(pose_i, pose_j)
        overall = np.mean(whitened_sq) / dof
        scales = np.ones(self.cells * self.cells)
        for r in range(len(scales)):
            sel = region == r
            if sel.sum() >= 5:
                scales[r] = np.mean(whitened_sq[sel]) / dof / max(overall, 1e-300)
        self.scales = scales
        return scales

    def scale_of(self, pose_i, pose_j):
        return self.scales[self.region(pose_i, pose_j)]

    def value(self, p=None):
        return float(np.max(self.scales) / max(np.min(self.scales), 1e-300))
