"""Plain data types the numerical core consumes: no rclpy, no rosbags.

The bag reader and the node both convert ROS messages into these, so the estimator
sees the same thing whether the data comes from a file or from the live graph.
"""
from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field

import numpy as np


@dataclass
class EncoderSample:
    """One JointState reduced to the two wheels: cumulative wheel angles in radians."""

    stamp: float  # s, header stamp
    left: float  # rad, cumulative (unwrapped) wheel angle
    right: float  # rad


@dataclass
class Scan:
    """One LaserScan: ranges in metres with the beam geometry needed to make points."""

    stamp: float  # s, header stamp (time of the first beam)
    ranges: np.ndarray  # (N,) m; inf / nan / out-of-limits mark no return
    angle_min: float  # rad
    angle_increment: float  # rad, may be negative (upside-down mounted scanners)
    range_min: float  # m
    range_max: float  # m
    time_increment: float = 0.0  # s between beams (0 when the driver does not say)
    frame_id: str = "laser"

    def angles(self) -> np.ndarray:
        return self.angle_min + self.angle_increment * np.arange(len(self.ranges))


@dataclass
class Rejections:
    """Counts of input rejected on purpose, by reason, so nothing is lost silently."""

    counts: Counter = field(default_factory=Counter)

    def add(self, reason: str, n: int = 1) -> None:
        self.counts[reason] += n

    def total(self) -> int:
        return sum(self.counts.values())

    def __str__(self) -> str:
        if not self.counts:
            return "none"
        return ", ".join(f"{reason}: {n}" for reason, n in sorted(self.counts.items()))
