"""The change test's use after every window solve: when a change of the radii is declared.

A load changes the radii at once. After every solve a likelihood-ratio test
(change.change_point) asks whether the radii changed at some chunk boundary of the history
or at the start of the pose window; above `config.statistic` on `config.confirmations`
solves in a row, a change is declared there, and the calibrator makes the data before that boundary
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
from sclam_ros.online.config import ChangeTestConfig


class ChangeDetector:
    """Counts the solves in a row whose change statistic is over the threshold, and the
    changes declared."""

    def __init__(self, config: ChangeTestConfig):
        self.config = config
        self.radius_changes = 0  # times a change of the radii was declared
        self.change_statistic = float("nan")  # of the last solve
        self._over_threshold = 0

    def restart(self) -> None:
        """The radii were forgotten: confirmations start again."""
        self._over_threshold = 0

    def testable(self, history_metres: float) -> bool:
        """Enough marginalised radii information to test against."""
        return history_metres >= self.config.min_tested_history

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
        # A change is looked for after the first `min_tested_history` metres of the
        # history: its first chunks after a start or a change are linearised at radii
        # still far off, and against them alone the ratio is high on clean driving.
        first = int(np.searchsorted(np.cumsum(job.history_metres),
                                    self.config.min_tested_history)) + 1
        found = change_point([*job.history, window], job.history_metres, fading_length,
                             job.reference, graph_mod.prior_sigmas(job.nominal),
                             first_boundary=first)
        self.change_statistic = found.statistic
        over = found.statistic > self.config.statistic
        self._over_threshold = self._over_threshold + 1 if over else 0
        if self._over_threshold < self.config.confirmations:
            return found, None
        self.radius_changes += 1
        # Chunks may have joined the history since the job was prepared: the boundary
        # is the chunk's number (or the pose window's start as it was then).
        numbers = [*job.history_numbers, job.next_chunk_number]
        return found, numbers[found.boundary]

    def radii_covariance(self, cov, found: ChangePoint, variance_factor: float) -> np.ndarray:
        """`cov` (6, 6) with the radii's block widened by the change `found` as far as the
        test believes in it (change.radii_covariance_with_change)."""
        cov[np.ix_(RADII, RADII)] = radii_covariance_with_change(
            cov[np.ix_(RADII, RADII)], found, change_weight(found.statistic, self.config.statistic),
            variance_factor)
        return cov
