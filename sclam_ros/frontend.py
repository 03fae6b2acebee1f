"""From sensor samples to graph keyframes: the one data path for live topics and bags.

Every scan that the encoders cover becomes a keyframe. Its edges to the previous keyframes:
  - the wheel angle increments since the previous keyframe (odometry edge), unless the
    encoder stream broke in between (gap, clock jump), and
  - the laser's motion from the last scan the matcher accepted (laser edge), unless the
    registration failed or the scan had no usable beams.

The scan matcher is seeded with the wheel-odometry prediction under the current
calibration, mapped into the laser frame: z_guess = l⁻¹ ∘ K ∘ l.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np

from . import kinematics, point_to_line
from .inputs import Rejections, Scan
from .scan_matching import (
    ScanMatcher,
    ScanMatcherConfig,
    laser_motion_from_base_motion,
    scan_to_points,
)
from .sync import EncoderStream, ScanSynchronizer, increment_between


@dataclass
class Keyframe:
    """One node of the graph and the measurements that tie it to earlier nodes."""

    index: int  # 0, 1, 2, ... in stamp order
    stamp: float  # s
    wheel_angles: np.ndarray  # (2,) rad, cumulative, at the scan stamp
    dphi: Optional[np.ndarray] = None  # (2,) increments since keyframe index − 1
    dphi_parts: Optional[np.ndarray] = None  # (n, 2) the same per scan, when merged
    laser_from: Optional[int] = None  # keyframe index the scan match is relative to
    laser_motion: Optional[np.ndarray] = None  # z: laser_j ⊖ laser_from, in that frame
    laser_information: Optional[np.ndarray] = None  # (3, 3)


class Frontend:
    """Feeds encoder samples and scans (in arrival order); returns finished keyframes."""

    def __init__(self, params, rejections: Optional[Rejections] = None, matcher=None):
        self.params = params
        self.rejections = rejections if rejections is not None else Rejections()
        self.stream = EncoderStream.from_params(params, rejections=self.rejections)
        self.sync = ScanSynchronizer(self.stream, self.rejections)
        self.matcher = matcher or ScanMatcher(
            ScanMatcherConfig.from_params(params), rejections=self.rejections
        )
        # The calibration used for the matcher's initial guess; the online estimator
        # updates it as it learns.
        self.calibration = np.array(
            [params.wheel_radius_left, params.wheel_radius_right, params.wheel_base,
             params.laser_x, params.laser_y, params.laser_yaw]
        )
        self._previous = None  # last SyncedScan
        self._count = 0
        # The last scan the matcher accepted, prepared for point-to-line refinement.
        self._reference = None
        self._reference_index = None

    def add_encoder(self, stamp: float, left_raw: float, right_raw: float) -> list:
        return [self._keyframe(s) for s in self.sync.add_encoder(stamp, left_raw, right_raw)]

    def add_scan(self, scan: Scan) -> list:
        return [self._keyframe(s) for s in self.sync.add_scan(scan)]

    def flush(self) -> list:
        return [self._keyframe(s) for s in self.sync.flush()]

    def _keyframe(self, synced) -> Keyframe:
        index = self._count
        self._count += 1
        kf = Keyframe(index, synced.scan.stamp, np.array(synced.wheels.angles, float))
        guess = None
        if self._previous is not None:
            increment, reason = increment_between(self._previous, synced, self.stream)
            if increment is not None:
                kf.dphi = np.asarray(increment.dphi, float)
                base_motion = kinematics.forward(kf.dphi, self.calibration[:3])
                guess = laser_motion_from_base_motion(base_motion, self.calibration[3:])
            else:
                self.rejections.add(reason)
        # The matcher is called once per keyframe, so its scan indices are keyframe indices.
        match = self.matcher.add_scan(synced.scan, guess)
        points = None
        if match is not None:
            z = np.asarray(match.z, float)
            points = scan_to_points(synced.scan, self.matcher.config.min_range,
                                    self.matcher.config.max_range)
            reference = self._reference if self._reference_index == match.index_from else None
            if reference is not None:
                z, _ = point_to_line.refine(reference, points, z)
            kf.laser_from = int(match.index_from)
            kf.laser_motion = z
            kf.laser_information = np.asarray(match.information, float)
        if match is not None or self._reference_index is None:
            if points is None:
                points = scan_to_points(synced.scan, self.matcher.config.min_range,
                                        self.matcher.config.max_range)
            self._reference = point_to_line.ReferenceScan.from_points(points)
            self._reference_index = index
        self._previous = synced
        return kf
