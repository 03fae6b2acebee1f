"""Motion during a sweep: what a moving laser's scan matches get wrong.

A laser whose beams sweep over a time T (beam at angle α taken T·(α − α_min)/span after
the stamp) sees each point from where it is at that beam's time (sclam_ros.sim's
``scan_motion``; the front end does not de-skew). Matched against the previous scan, a
scan registers as the laser pose of some instant inside its sweep, with a deformation on
top. Two errors of a match z between scans i and j follow (their sizes on simulated
sweeps: docs/decisions/diagnose.md):

1. delay τ: the match is the laser's motion between instants τ after the two stamps,
   τ ≈ T/2, the mean beam time (every beam constrains the heading alike). To first
   order that is a clock offset, the correction dφ + τ·(ω_j − ω_i) of the wheel
   increments that ``time_offset`` makes with δ = τ, and no regressor of these data
   separates the two.
2. shift g·(ω_j − ω_i): turning at ω, beam α is rotated by ω·T·(α − α_mid)/span
   against the mid-sweep pose, so walls ahead and behind (across the seam, where the
   first and last beams meet) appear displaced along the laser's x by about ω·T times
   their lateral extent. When the turn rate changes between two scans, the match moves
   by g·Δω, g = T·L with L a length of the scene. At a constant turn rate both scans
   are deformed alike and the match is right (on-the-spot turns: no error), so the shift
   is additive in Δω, not a fixed offset of each scan's pose (which, turned with the
   scan, would show at constant turning and put sideways error on on-the-spot turns
   whose matches have none).
   Nothing in the wheels produces this: it is what tells a sweep from a clock offset.

The model: the odometry edge is predicted over the delayed window, dφ + τ·(ω_j − ω_i)
with the wheel speeds ω, and the match is corrected for the shift,
    z' = z + (g_x, g_y, 0)·(ω_j − ω_i),
ω_k the turn rate at scan k from the scan matches themselves (EffectData.turn_rates: no
wheel calibration enters). Parameters (τ, g_x, g_y) in s, m·s, m·s; the value reported
is τ. With all at 0 both edges are unchanged.

The delay is what the scans state: a LaserScan's time_increment says when each beam was
taken, so τ's prior is centred on half the stated sweep (EffectData.sweep_delay; 0 for a
scan that states time_increment 0, taken at once) with σ stated_delay_sigma. A delay the
stated sweep does not explain is then a clock offset between encoders and laser, which
time_offset reports, not a sweep: a clock offset and a sweep delay are one parameter to
first order, and only the scans' own statement tells them apart. Where nothing is known of
the sweep (EffectData without keyframes), τ's prior is the weak zero-mean one.
"""
from __future__ import annotations

import numpy as np

from sclam_ros.diagnosis.effects.base import ModelEffect
from sclam_ros.diagnosis.effects.time_offset import clock_shift


class ScanDistortion(ModelEffect):
    name = "scan_distortion"
    kind = "odometry+laser"
    dim = 3
    units = "s (delay τ; then g_x, g_y in m·s)"
    doc = "a moving sweep's match errors: delay τ of the mean beam, shift g·Δω of a changing turn"
    prior_sigma = 1.0
    # s, 1σ of τ about the stated sweep's half: a driver stamps its first beam or its
    # nominal start, and its time_increment is the beam period to a fraction of a beam
    stated_delay_sigma = 0.002

    def prior(self):
        mean, sigma = super().prior()
        if self.data.sweep_delay is not None:
            mean[0], sigma[0] = self.data.sweep_delay, self.stated_delay_sigma
        return mean, sigma

    def adjust_dphi(self, dphi, p, i, j):
        shifted, d_dphi, d_tau = clock_shift(self.data, dphi, p[0], i, j)
        d_p = np.zeros((len(dphi), 2, self.dim))
        d_p[:, :, :1] = d_tau
        return shifted, d_dphi, d_p

    def adjust_z(self, z, p, i, j):
        change = self.data.turn_rates[j] - self.data.turn_rates[i]
        corrected = z.copy()
        corrected[:, :2] += np.outer(change, p[1:3])
        d_p = np.zeros((len(z), 3, self.dim))
        d_p[:, 0, 1] = d_p[:, 1, 2] = change
        return corrected, d_p
