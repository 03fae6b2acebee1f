"""Clock offset δ between the encoders and the laser.

Encoder stamps = true sampling time + δ, laser stamps true. The increments synchronised to
scan stamps t_i, t_j are then those of [t_i − δ, t_j − δ]; to first order the true
increments over [t_i, t_j] are dφ + δ·(ω_j − ω_i), with ω the wheel angular speeds at
the two stamps (from the per-scan wheel angles, see EffectData). δ > 0: the encoders'
clock is ahead.
"""
from __future__ import annotations

import numpy as np

from .base import ModelEffect


class TimeOffset(ModelEffect):
    name = "time_offset"
    units = "s"
    doc = "encoder clock ahead of the laser clock by δ"
    prior_sigma = 0.5

    def adjust_dphi(self, dphi, p, i, j):
        w = self.data.wheel_speeds
        change = w[j] - w[i]  # (m, 2)
        m = len(dphi)
        return (dphi + p[0] * change, np.broadcast_to(np.eye(2), (m, 2, 2)),
                change[:, :, None])
