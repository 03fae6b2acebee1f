"""Clock offset δ between the encoders and the laser.

Encoder stamps = true sampling time + δ, laser stamps true. The increments synchronised to
scan stamps t_i, t_j are then those of [t_i − δ, t_j − δ]; to first order the true
increments over [t_i, t_j] are dφ + δ·(ω_j − ω_i), with ω the wheel angular speeds at
the two stamps (from the per-scan wheel angles, see EffectData). δ > 0: the encoders'
clock is ahead.
"""
from __future__ import annotations

import numpy as np

from sclam_ros.diagnosis.effects.base import ModelEffect


class TimeOffset(ModelEffect):
    name = "time_offset"
    units = "s"
    doc = "encoder clock ahead of the laser clock by δ"
    prior_sigma = 0.5

    def adjust_dphi(self, dphi, p, i, j):
        return clock_shift(self.data, dphi, p[0], i, j)


def clock_shift(data, dphi, delta, i, j):
    """The increments of the window [t_i, t_j] shifted by δ, to first order, with their
    Jacobians wrt dφ (m,2,2) and δ (m,2,1)."""
    change = data.wheel_speeds[j] - data.wheel_speeds[i]  # (m, 2)
    return (dphi + delta * change, np.broadcast_to(np.eye(2), (len(dphi), 2, 2)),
            change[:, :, None])
