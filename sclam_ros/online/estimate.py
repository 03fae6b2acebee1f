"""What the online calibrator reports: its current Estimate and a CalibratorStatus snapshot."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional

import numpy as np

from sclam_ros.core.params import CALIBRATION_KEYS
from sclam_ros.frontend.report import FrontendReport


@dataclass
class Estimate:
    """The current calibration and its marginal uncertainty, as it may be published: a
    parameter the data did not determine is at its nominal value with its prior σ."""

    stamp: float
    values: dict  # the six CALIBRATION_KEYS
    sigma: dict
    covariance: np.ndarray  # (6, 6)
    keyframes_in_window: int
    window_distance: float  # m covered by the window
    converged: bool = True
    # edge type ("odometry", "laser") -> (3,) RMS of the raw residuals (m, m, rad)
    residual_rms: dict = field(default_factory=dict)
    # CALIBRATION_KEYS -> the data determines it (core/observability.py)
    observable: dict = field(default_factory=lambda: dict.fromkeys(CALIBRATION_KEYS, True))

    def vector(self):
        return np.array([self.values[k] for k in CALIBRATION_KEYS])


@dataclass(frozen=True)
class CalibratorStatus:
    """What is reported of an OnlineCalibrator, copied out of it: safe to hand to another
    thread or process while the calibrator goes on (see online/process.py)."""

    estimate: Optional[Estimate]
    calibration: np.ndarray  # (6,) the values in use: the estimate's (unobserved at nominal)
    nominal: np.ndarray  # (6,)
    observable: dict  # CALIBRATION_KEYS -> bool (all False before the first estimate)
    window_keyframes: int
    window_length: float  # m the radii are estimated from (poses + marginalised chunks)
    pose_window_length: float  # m of it still held as poses
    window_distance: float  # m, the configured radii memory (change.py)
    radius_changes: int
    change_statistic: float  # of the last solve (nan before the first test)
    solves: int
    unconverged_in_a_row: int
    frontend: FrontendReport  # scans skipped, matches made and confirmed, the laser's noise
