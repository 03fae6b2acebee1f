"""Which scans are matched: about MATCH_PERIOD apart, whatever the laser's rate.

A scan match carries a small bias that does not shrink with the motion between the scans:
matched scan by scan, a 40 Hz laser's displacements come out 0.26 % short against 0.00 % at
10 Hz on the same route (bench/scan_matching_accuracy.py --factors), and that bias goes
straight into the wheel radii. Matching every n-th scan of a fast laser keeps each match as
long as a 10 Hz laser's, and costs a quarter of the registrations at 40 Hz. Keyframes merge
scans into keyframe_interval edges anyway, so no information the graph uses is lost: the
errors of consecutive matches are negatively correlated and do not average out by matching
more often.

The rule depends on the stamps only, not on where reading started: n = round(MATCH_PERIOD /
the median period of the first scans), and a scan is matched when it is the first seen in its
bin of the time grid of width n·period. A recording cut into chunks (sclam_ros/fleet/chunked.py)
therefore matches the same scans in every chunk as in one sequential pass, and a laser at up
to ~13 Hz is never thinned (n = 1).
"""
from __future__ import annotations

import math
from typing import Optional

import numpy as np

MATCH_PERIOD = 0.1  # s: the spacing of matches the scan-match noise model was measured at
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
                self.every = max(1, round(self.match_period / period)) if period > 0 else 1
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
