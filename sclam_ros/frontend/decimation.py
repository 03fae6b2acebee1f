"""Which scans are matched: about DecimationConfig.match_period apart, whatever the laser's rate.

A scan match carries an error that does not shrink with the motion between the scans, so
matching scans close together multiplies it: scan matching follows its starting point (the
wheel odometry under the nominal calibration) part of the way, and on noisy lasers it sticks
to a start near zero motion; both shorten the matched displacements and go straight into the
wheel radii. Matching every n-th scan also saves registrations. Keyframes merge matches into
keyframe_interval edges anyway, so no information the graph uses is lost: the errors of
consecutive matches are negatively correlated and do not average out by matching more often.

Encoders slower than the matching (1-2 Hz odometry) get the first scan after each of their
samples matched, and between samples scans at least the match period apart and not within
half of it before the next sample: graph.merge_keyframes ends the odometry edges at the
scans after samples, where the wheel angles are nearly exact, so the straight line between
samples (wrong wherever the robot turned in part of an encoder interval) cancels inside
each edge.

The rule depends on the stamps only, not on where reading started: n = match_period / the
median period of the first scans, rounded (halves up), and a scan is matched when it is the
first seen in its bin of the time grid of width n·period. A recording cut into chunks
(sclam_ros/fleet/chunked.py) therefore matches the same scans in every chunk as in one
sequential pass (with slow encoders, from its first few encoder samples on: the scans
follow the samples). At 0.3 s a laser slower than ~4.5 Hz is never thinned (n = 1); at the
online calibrator's 0.1 s one slower than ~13 Hz.

The measurements: docs/decisions/scan_matching.md, "Matching every n-th scan".
"""
from __future__ import annotations

import math
from typing import Optional

import numpy as np

from sclam_ros.frontend.config import DecimationConfig


def scan_period(stamps) -> float:
    """s: the laser's period from the stamps of its first scans (the median positive step;
    0 if none is)."""
    periods = np.diff(stamps)
    return float(np.median(periods[periods > 0])) if np.any(periods > 0) else 0.0


class ScanDecimator:
    """``accept(stamp, ...)``: True for the scans to match. Counts the others in ``skipped``."""

    def __init__(self, match_period: Optional[float] = None,
                 config: DecimationConfig = DecimationConfig(), scan_period: Optional[float] = None):
        """match_period: s, config.match_period unless given (the online calibrator's).
        scan_period: s, the laser's period as scan_period() measured it on the recording's
        first scans, for a reader that starts later (a chunk of it: fleet/chunked.py), so
        that it matches the scans a reader from the start matches; None: measured here."""
        self.config = config
        self.match_period = config.match_period if match_period is None else match_period
        self.skipped = 0
        self.every: Optional[int] = None  # n, once the rate is known
        self._stamps: list[float] = []
        self._bin_width = None
        self._last_bin = None
        self._last_accepted = None  # stamp of the last scan accepted
        self.follows_samples = False  # the encoders were slower than the matching: see above
        if scan_period is not None:
            self._set_period(scan_period)

    def _set_period(self, period: float) -> None:
        # Halves round up, and a period a hair long (0.2000001 s) still gives 1.5 → 2.
        self.every = max(1, math.floor(self.match_period / period + 0.5 + 1e-6)) if period > 0 else 1
        self._bin_width = self.every * period

    def accept(self, stamp: float, last_sample: Optional[float] = None,
               sample_period: Optional[float] = None) -> bool:
        """last_sample, sample_period: the newest encoder sample's stamp and the encoders'
        period, where known (encoders slower than the matching place the scans matched:
        see above)."""
        accepted = self._accept(stamp, last_sample, sample_period)
        if accepted:
            self._last_accepted = stamp
        return accepted

    def _accept(self, stamp, last_sample, sample_period) -> bool:
        if self.every is None:
            self._stamps.append(stamp)
            if len(self._stamps) > self.config.rate_sample:
                self._set_period(scan_period(self._stamps))
            return True  # every scan while the rate is being measured
        if self.every == 1:
            return True
        if last_sample is not None and sample_period is not None and sample_period > self._bin_width:
            self.follows_samples = True
            accepted = self._on_sample_grid(stamp, last_sample, sample_period)
        else:
            current = math.floor(stamp / self._bin_width)
            accepted = current != self._last_bin
            self._last_bin = current
        if not accepted:
            self.skipped += 1
        return accepted

    def _on_sample_grid(self, stamp, last_sample, sample_period) -> bool:
        """Slow encoders: the first scan at or after each sample, and between samples scans
        at least a bin width after the last one matched and half a bin width before the
        next sample is due (no match much shorter than the others)."""
        if self._last_accepted is None or self._last_accepted < last_sample <= stamp:
            return True
        return (stamp - self._last_accepted >= self._bin_width - 1e-6
                and last_sample + sample_period - stamp >= 0.5 * self._bin_width)
