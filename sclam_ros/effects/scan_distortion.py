"""Motion during a scan: a sweeping laser sees a moving robot's surroundings distorted,
and the scan match under- or over-states the motion in proportion to it.

z' = (1 + c)·z, translation and rotation alike (c dimensionless): the measured laser
motion, corrected, is what the laser really did.
"""
from __future__ import annotations

from .base import ModelEffect


class ScanDistortion(ModelEffect):
    name = "scan_distortion"
    kind = "laser"
    units = "1"
    doc = "scan-match displacement scaled by (1 + c)"
    prior_sigma = 1.0

    def adjust_z(self, z, p, i, j):
        return (1.0 + p[0]) * z, z[:, :, None].copy()
