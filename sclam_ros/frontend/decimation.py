"""Which scans are matched: about MATCH_PERIOD apart, whatever the laser's rate.

A scan match carries an error that does not shrink with the motion between the scans, so
matching scans close together multiplies it: scan matching follows its starting point (the
wheel odometry under the nominal calibration) part of the way, and on noisy lasers it sticks
to a start near zero motion; both shorten the matched displacements and go straight into the
wheel radii. Measured with `python bench/sensor_matrix.py --seeds 10 --duration 120`
(PowerBot; match scale = matched / true displacement), scans matched 0.1 s apart against
0.3 s apart, nothing else changed:

    URG-04LX-like (3 cm, 5.6 m): match scale 0.9904 / 0.9940, radii mean error −0.72 / −0.39 %
    5 cm range noise:            match scale 0.9934 / 0.9977, radii mean error −0.78 / −0.17 %
    odometry at 2 Hz:            wheel base mean error −0.72 / −0.17 %
    default (1 cm):              the same within noise

and a 40 Hz laser's matches scan by scan come out 0.26 % short (bench/scan_matching_accuracy.py
--factors). Matching every n-th scan also costs a third of the registrations at 10 Hz and a
twelfth at 40 Hz. Keyframes merge matches into keyframe_interval edges anyway, so no
information the graph uses is lost: the errors of consecutive matches are negatively
correlated and do not average out by matching more often.

The rule depends on the stamps only, not on where reading started: n = MATCH_PERIOD / the
median period of the first scans, rounded (halves up), and a scan is matched when it is the
first seen in its bin of the time grid of width n·period. A recording cut into chunks
(sclam_ros/fleet/chunked.py) therefore matches the same scans in every chunk as in one
sequential pass. At MATCH_PERIOD a laser slower than ~4.5 Hz is never thinned (n = 1); at
ONLINE_MATCH_PERIOD one slower than ~13 Hz.
"""
from __future__ import annotations

import math
from typing import Optional

import numpy as np

MATCH_PERIOD = 0.3  # s between matched scans (see above)
# The online calibrator (the node, `sclam calibrate --track`) matches 0.1 s apart: its guess
# is its own running estimate, so the guess leak does not build up, and its change-point
# test and fading memory follow a load change better with the denser edges. Measured with
# `python bench/load_change.py --seeds 5`, 0.1 s / 0.3 s: a 1 % step found after 16 / 21 s
# (median), radii from +30 s within 0.33 / 0.93 %, a 0.5 % one-wheel step found on 5 / 4
# of 5 seeds.
ONLINE_MATCH_PERIOD = 0.1
RATE_SAMPLE = 20  # scan periods the laser's rate is judged from


class ScanDecimator:
    """``accept(stamp)``: True for the scans to match. Counts the others in ``skipped``."""

    def __init__(self, match_period: float = MATCH_PERIOD):
        self.match_period = match_period
        self.skipped = 0
        self.every: Optional[int] = None  # n, once the rate is known
        self._stamps: list[float] = []
        self._bin_width = None
        self._last_bin = None

    def accept(self, stamp: float) -> bool:
        if self.every is None:
            self._stamps.append(stamp)
            if len(self._stamps) > RATE_SAMPLE:
                periods = np.diff(self._stamps)
                period = float(np.median(periods[periods > 0])) if np.any(periods > 0) else 0.0
                # Halves round up, and a period a hair long (0.2000001 s) still gives 1.5 → 2.
                self.every = max(1, math.floor(self.match_period / period + 0.5 + 1e-6)) if period > 0 else 1
                self._bin_width = self.every * period
            return True  # every scan while the rate is being measured
        if self.every == 1:
            return True
        current = math.floor(stamp / self._bin_width)
        if current == self._last_bin:
            self.skipped += 1
            return False
        self._last_bin = current
        return True
