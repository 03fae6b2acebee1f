"""The change test's use after every window solve: when a change of the radii is declared.

A load changes the radii at once. After every solve a likelihood-ratio test
(change.change_point) asks whether the radii changed at some chunk boundary of the history
or at the start of the pose window; above CHANGE_STATISTIC on CHANGE_CONFIRMATIONS solves in
a row, a change is declared there, and the calibrator makes the data before that boundary
one segment whose radii are integrated out jointly (history.forget_radii). So a long memory
(precise radii while nothing changes) neither makes the estimate slow to follow a change nor
lets the old radii into the wheel base and laser. Until it is declared, the published radii's
σ weighs in the change as far as the test believes in it (radii_covariance).
"""
from __future__ import annotations

from typing import Optional

import numpy as np

from sclam_ros.core import graph as graph_mod
from sclam_ros.core.marginal import RADII, Gaussian
from sclam_ros.online.change import (ChangePoint, change_point, change_weight,
                                     radii_covariance_with_change)

# A radius change is declared when the change point's likelihood ratio (change.py) exceeds
# CHANGE_STATISTIC on CHANGE_CONFIRMATIONS solves in a row. At one boundary fixed in advance
# the ratio would be a χ² with 2 dof; the test takes the largest over the ~45 boundaries of
# a 100 m history, and the window's noise model overstates the noise (the batch solve's
# variance factors are 0.25-0.46, bench/online_sigma.py), which shrinks the ratio by as
# much. Measured on clean 6-10 minute recordings (bench/load_change.py): no false alarm in
# 50 minutes; a 1 % step is detected 12-25 s after it.
CHANGE_STATISTIC = 6.0
CHANGE_CONFIRMATIONS = 3
# The test needs a reference: marginalised data of at least this many metres, and a change
# is placed no earlier than after the history's first this many metres. Chunks right after
# the start are linearised around radii still converging from nominal: against the first
# one alone the ratio sat at 3-6 for minutes of clean driving.
MIN_TESTED_HISTORY = 10.0


class ChangeDetector:
    """Counts the solves in a row whose change statistic is over the threshold, and the
    changes declared."""

    def __init__(self):
        self.radius_changes = 0  # times a change of the radii was declared
        self.change_statistic = float("nan")  # of the last solve
        self._over_threshold = 0

    def restart(self) -> None:
        """The radii were forgotten: confirmations start again."""
        self._over_threshold = 0

    @staticmethod
    def testable(history_metres: float) -> bool:
        """Enough marginalised radii information to test against."""
        return history_metres >= MIN_TESTED_HISTORY

    def test(self, job, mean, cov, observable,
             fading_length: float) -> tuple[Optional[ChangePoint], Optional[int]]:
        """The change test on a solve of `job` (window_solve.SolveJob) with posterior `mean`
        and `cov` (None where it cannot be made), and the number of the chunk before which
        the radii changed when this solve confirms a change (else None)."""
        # A parameter held at nominal carries a lock's information, not the data's.
        if not job.change_testable or not all(observable.values()):
            self.change_statistic = float("nan")
            return None, None
        # The pose window's own information: the solve's posterior less its priors.
        information = np.linalg.inv(cov)
        information = 0.5 * (information + information.T)
        window = Gaussian(information - job.prior.information, information @ mean - job.prior.eta)
        # A change is looked for after the first MIN_TESTED_HISTORY metres of the history:
        # its first chunks after a start or a change are linearised at radii still far
        # off, and against them alone the ratio sat at 3-6 for minutes of clean driving.
        first = int(np.searchsorted(np.cumsum(job.history_metres), MIN_TESTED_HISTORY)) + 1
        found = change_point([*job.history, window], job.history_metres, fading_length,
                             job.reference, graph_mod.prior_sigmas(job.nominal),
                             first_boundary=first)
        self.change_statistic = found.statistic
        self._over_threshold = self._over_threshold + 1 if found.statistic > CHANGE_STATISTIC else 0
        if self._over_threshold < CHANGE_CONFIRMATIONS:
            return found, None
        self.radius_changes += 1
        # Chunks may have joined the history since the job was prepared: the boundary
        # is the chunk's number (or the pose window's start as it was then).
        numbers = [*job.history_numbers, job.next_chunk_number]
        return found, numbers[found.boundary]

    @staticmethod
    def radii_covariance(cov, found: ChangePoint, variance_factor: float) -> np.ndarray:
        """`cov` (6, 6) with the radii's block widened by the change `found` as far as the
        test believes in it (change.radii_covariance_with_change)."""
        cov[np.ix_(RADII, RADII)] = radii_covariance_with_change(
            cov[np.ix_(RADII, RADII)], found, change_weight(found.statistic, CHANGE_STATISTIC),
            variance_factor)
        return cov
