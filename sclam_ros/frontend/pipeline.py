"""From sensor samples to graph keyframes: the one data path for live topics and bags.

Every scan that is matched (every n-th, about match_period apart: 0.3 s in batch, 0.1 s in
the online calibrator; with slower encoders also the scan just after each of their samples:
frontend/decimation.py) and that the encoders cover becomes a keyframe. Its edges to the previous keyframes:
  - the wheel angle increments since the previous keyframe (odometry edge), unless the
    encoder stream broke in between (gap, clock jump), and
  - the laser's motion from the last scan the matcher accepted (laser edge), unless the
    registration failed, the scan had no usable beams, or the point-to-line refinement could
    not confirm it (frontend/point_to_line.py: no lines, an outdoor scene).

The scan matcher is seeded with the wheel-odometry prediction under the current
calibration, mapped into the laser frame: z_guess = l⁻¹ ∘ K ∘ l.

A scan is registered as soon as it arrives, not when the encoders reach its stamp: a scan
that waits for the next encoder sample (up to a whole encoder period, 10 ms at 100 Hz,
33 ms for a 30 Hz TurtleBot) would otherwise wait before its registration, too. Its seed
then uses the wheel angles extrapolated from the last two samples (a few ms at constant
speed: far inside the matcher's basin); its odometry edge waits for the real samples.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np

from sclam_ros.core import kinematics
from sclam_ros.core.inputs import Rejections, Scan
from sclam_ros.core.keyframe import Keyframe
from sclam_ros.frontend.config import FrontendConfig
from sclam_ros.frontend.decimation import ScanDecimator
from sclam_ros.frontend.point_to_line import RefinedScanMatcher
from sclam_ros.frontend.report import FrontendReport
from sclam_ros.frontend.scan_matching import (
    ScanMatcher,
    ScanMatcherConfig,
    laser_motion_from_base_motion,
    scan_to_points,
    thinned,
)
from sclam_ros.frontend.encoder_stream import EncoderStream
from sclam_ros.frontend.sync import ScanSynchronizer, increment_between


@dataclass
class _Registration:
    """What the matcher made of one scan (the matcher numbers the scans it is given)."""

    scan: Scan
    number: int
    match_from: Optional[int] = None  # number of the scan the motion is relative to
    laser_motion: Optional[np.ndarray] = None
    laser_information: Optional[np.ndarray] = None
    points: Optional[np.ndarray] = None  # (n, 2) laser frame, if the front end keeps them


class Frontend:
    """Feeds encoder samples and scans (in arrival order); returns finished keyframes."""

    def __init__(self, params, rejections: Optional[Rejections] = None, matcher=None,
                 match_period: Optional[float] = None, keep_scan_points: bool = False,
                 config: FrontendConfig = FrontendConfig(), scan_period: Optional[float] = None):
        self.params = params  # the user's (SclamParams); config is the developer's tuning
        # Keyframes carry their scan's points (Keyframe.scan_points): for the diagnosis's
        # map of walls, not for the calibration (an hour of 360-beam scans matched every
        # 0.3 s is ~35 MB of them).
        self.keep_scan_points = keep_scan_points
        self.rejections = rejections if rejections is not None else Rejections()
        self.stream = EncoderStream.from_params(params, config.sync, self.rejections)
        self.sync = ScanSynchronizer(self.stream, self.rejections)
        self.matcher = matcher or ScanMatcher(
            ScanMatcherConfig.from_params(params), rejections=self.rejections
        )
        self.refined_matcher = RefinedScanMatcher(self.matcher, config)
        # The calibration used for the matcher's initial guess; the online estimator
        # updates it as it learns.
        self.calibration = np.array(params.calibration_vector())
        self._previous = None  # last SyncedScan
        self._count = 0
        self._registered_angles = None  # WheelAngles (maybe predicted) of the last one
        self._early = None  # _Registration of a scan still waiting for the encoders
        self._keyframe_of = {}  # registration number -> keyframe index
        # scans matched about match_period apart (None: config.decimation.match_period)
        # scan_period: the laser's, measured on the recording's first scans where this front
        # end starts later (ScanDecimator)
        self.decimator = ScanDecimator(match_period, config.decimation, scan_period)
        self._remembered = config.remembered_registrations

    @property
    def registered(self) -> int:
        """Scans given to the matcher so far (a registration's number is the matcher's)."""
        return self.matcher.next_index

    def add_encoder(self, stamp: float, left_raw: float, right_raw: float) -> list:
        return [self._keyframe(s) for s in self.sync.add_encoder(stamp, left_raw, right_raw)]

    def report(self) -> FrontendReport:
        """What it did so far: matches made and confirmed, scans skipped, the laser's noise."""
        return FrontendReport.of(self)

    def add_scan(self, scan: Scan) -> list:
        if not self.decimator.accept(scan.stamp, self.stream.latest_stamp, self.stream.period):
            return []
        keyframes = [self._keyframe(s) for s in self.sync.add_scan(scan)]
        pending = self.sync.pending
        if len(pending) == 1 and pending[0] is scan:
            # Only this scan waits: register it now. (Behind another waiting scan it keeps
            # its turn: the matcher must see scans in order.)
            predicted = self.stream.predict(scan.stamp)
            if predicted is not None:
                self._early = self._register(scan, predicted)
        return keyframes

    def flush(self) -> list:
        return [self._keyframe(s) for s in self.sync.flush()]

    def _register(self, scan: Scan, angles) -> _Registration:
        """Run the matcher (and the point-to-line refinement) on `scan` taken at wheel
        `angles`; the seed is the wheel motion since the previously registered scan."""
        guess = None
        last, self._registered_angles = self._registered_angles, angles
        if last is not None and last.segment == angles.segment and angles.stamp > last.stamp:
            base_motion = kinematics.forward(angles.angles - last.angles, self.calibration[:3])
            guess = laser_motion_from_base_motion(base_motion, self.calibration[3:])
        registration = _Registration(scan, self.registered)
        scan = thinned(scan, self.params.scan_max_beams)
        config = self.matcher.config
        points = scan_to_points(scan, config.min_range, config.max_range)
        match, z, information = self.refined_matcher.add_scan(scan, guess, points)
        if self.keep_scan_points:
            registration.points = np.asarray(points[:, :2], np.float32)
        if z is not None:
            registration.match_from = int(match.index_from)
            registration.laser_motion = z
            registration.laser_information = information
        return registration

    def _keyframe(self, synced) -> Keyframe:
        index = self._count
        self._count += 1
        kf = Keyframe(index, synced.scan.stamp, np.array(synced.wheels.angles, float),
                      angle_variance=np.array(synced.wheels.variance, float),
                      since_sample=float(synced.wheels.since_sample),
                      sweep=abs(float(synced.scan.time_increment)) * max(len(synced.scan.ranges) - 1, 0))
        if self._previous is not None:
            increment, reason = increment_between(self._previous, synced, self.stream)
            if increment is not None:
                kf.dphi = np.asarray(increment.dphi, float)
                if len(synced.between):  # one arc per stretch between encoder samples
                    cuts = np.vstack([self._previous.wheels.angles, synced.between,
                                      synced.wheels.angles])
                    kf.dphi_parts = np.diff(cuts, axis=0)
                # Both ends in one encoder segment: their cumulative path variances differ
                # by the intervals completed in between.
                kf.path_variance = max(
                    float(synced.wheels.path_variance - self._previous.wheels.path_variance), 0.0)
            else:
                self.rejections.add(reason)
        early, self._early = self._early, None
        # An early registration of a scan the synchroniser then dropped is simply unused.
        if early is not None and early.scan is synced.scan:
            registration = early
        else:
            registration = self._register(synced.scan, synced.wheels)
        kf.scan_points = registration.points
        self._keyframe_of[registration.number] = index
        if len(self._keyframe_of) > self._remembered:
            del self._keyframe_of[next(iter(self._keyframe_of))]
        if registration.laser_motion is not None:
            source = self._keyframe_of.get(registration.match_from)
            if source is None:  # the reference scan was registered, then dropped
                self.rejections.add("laser_edge_from_dropped_scan")
            else:
                kf.laser_from = source
                kf.laser_motion = registration.laser_motion
                kf.laser_information = registration.laser_information
        self._previous = synced
        return kf
