"""Lateral skid in turns: the body moves sideways with vy = −g·v·ω, unseen by the wheels.

Over an edge of duration T with arc length s and heading change θ, v·ω ≈ s·θ/T², so the
sideways displacement is −g·s·θ/T, taken along the body's mid-edge heading θ/2:
Δm = −g·s·θ/T · (−sin θ/2, cos θ/2, 0). g in s.
"""
from __future__ import annotations

import numpy as np

from sclam_ros.core import kinematics
from sclam_ros.diagnosis.effects.base import ModelEffect


class LateralSlip(ModelEffect):
    name = "lateral_slip"
    units = "s"
    doc = "sideways skid vy = −g·v·ω"
    prior_sigma = 1.0

    def motion_term(self, dphi, k, p, i, j):
        g = p[0]
        duration = np.maximum(self.data.stamps[j] - self.data.stamps[i], 1e-3)
        s, theta = kinematics.arc_length_and_rotation(dphi, k)
        half = 0.5 * theta
        direction = np.stack([-np.sin(half), np.cos(half)], -1)  # (m, 2)
        d_direction = 0.5 * np.stack([-np.cos(half), -np.sin(half)], -1)  # ∂/∂θ
        amount = -s * theta / duration  # displacement per unit g
        term = np.zeros((len(dphi), 3))
        term[:, :2] = g * amount[:, None] * direction
        # Partials of s and θ.
        r_l, r_r, b = (np.broadcast_to(k[..., c], s.shape) for c in range(3))
        ds_du = np.stack([0.5 * r_l, 0.5 * r_r], -1)
        dth_du = np.stack([-r_l / b, r_r / b], -1)
        ds_dk = np.stack([0.5 * dphi[:, 0], 0.5 * dphi[:, 1], np.zeros_like(s)], -1)
        dth_dk = np.stack([-dphi[:, 0] / b, dphi[:, 1] / b, -theta / b], -1)

        def chain(ds, dth):
            d_amount = (-theta / duration)[:, None] * ds + (-s / duration)[:, None] * dth
            out = np.zeros((len(dphi), 3, ds.shape[1]))
            out[:, :2, :] = g * (direction[:, :, None] * d_amount[:, None, :]
                                 + (amount[:, None] * d_direction)[:, :, None] * dth[:, None, :])
            return out

        d_p = np.zeros((len(dphi), 3, 1))
        d_p[:, :2, 0] = amount[:, None] * direction
        return term, chain(ds_du, dth_du), chain(ds_dk, dth_dk), d_p
