"""Wheel radii drifting linearly in time (tyre wear, warming up, a slow leak).

r_l(t) = r_l·(1 + a_l·τ), r_r(t) = r_r·(1 + a_r·τ), τ = (t − t_ref) / 3600 s at the edge's
mid-time, t_ref mid-run so (r_l, r_r) remain the run's mean radii. a in fraction/hour,
the unit of the simulator's effect of the same name.
"""
from __future__ import annotations

import numpy as np

from sclam_ros.diagnosis.effects.base import ModelEffect, largest_signed


class RadiusDrift(ModelEffect):
    name = "radius_drift"
    dim = 2
    units = "fraction/hour"
    doc = "radii change linearly in time: (a_left, a_right)"
    prior_sigma = 10.0
    # A drift in time is also one with the distance driven (the robot drives on).
    signature = ("time", "distance")

    def adjust_k(self, k, p, i, j):
        t = self.data.stamps
        tau = (0.5 * (t[i] + t[j]) - self.data.reference_time) / 3600.0
        m = len(k)
        factor = np.stack([1.0 + p[0] * tau, 1.0 + p[1] * tau, np.ones(m)], -1)
        d_k = np.zeros((m, 3, 3))
        d_k[:, [0, 1, 2], [0, 1, 2]] = factor
        d_p = np.zeros((m, 3, 2))
        d_p[:, 0, 0] = k[:, 0] * tau
        d_p[:, 1, 1] = k[:, 1] * tau
        return k * factor, d_k, d_p

    def value(self, p):
        """The drift of the larger-drifting wheel (fraction/hour), signed."""
        return largest_signed(p)
