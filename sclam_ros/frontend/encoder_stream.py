"""Encoder stream conditioning: raw JointState wheel positions in, cumulative wheel angles out.

:class:`EncoderStream` turns raw wheel positions, fed one at a time, into a clean, bounded
history of cumulative wheel angles (rad): counter wrap-around unwrapped, ticks converted to
radians, bad samples rejected and counted, and the history cut into *segments* wherever it
cannot be trusted to be continuous (a gap, a clock jump, an absurd jump of the counter).
Wheel angles are interpolated only inside a segment. It works online (a node feeding
messages as they arrive) and offline (a bag read in record order) with the same code, and
keeps memory bounded; frontend/sync.py pairs its angles with the scans.

Why interpolate: encoders (typ. 20–100 Hz) and the laser (typ. 10 Hz) are not synchronised;
taking the nearest encoder sample would put up to half an encoder period (0.5 cm at 1 m/s
and 100 Hz, more at 20 Hz) of timing error into every odometry edge, correlated with speed,
which the calibration would absorb into the wheel radii. Linear interpolation is exact for
constant wheel speed between two samples. Where the speed changes between samples it is
not, and on slow odometry (1-2 Hz) that error is larger than the wheels' slip noise and
biased with the drive: there the angles are taken on a cubic through the two samples
before and the two after the stamp (SyncConfig.curved_interval; Catmull-Rom: exact for
constant acceleration and symmetric in time); a scan waits for the second sample after it
(EncoderStream.settled). Each interpolated angle carries the variance of the line's
interpolation error (EncoderStream._off_line), which the odometry edges add to their
covariance. The measurements: docs/decisions/slow_odometry.md.
"""
from __future__ import annotations

import bisect
import math
from collections import Counter, deque
from dataclasses import dataclass, field
from typing import Optional

import numpy as np

from sclam_ros.core.inputs import EncoderSample, Rejections
from sclam_ros.frontend.config import SyncConfig


@dataclass
class WheelAngles:
    """Cumulative wheel angles (left, right) in rad at ``stamp``, in encoder ``segment``."""

    stamp: float
    angles: np.ndarray  # (2,) rad
    segment: int
    # (2,) rad²: variance of `angles` from interpolating between samples (0 at a sample)
    variance: np.ndarray = field(default_factory=lambda: np.zeros(2))
    since_sample: float = 0.0  # s from the last sample at or before `stamp`
    # rad⁴: the path variance (EncoderStream._path_variance) of the segment's encoder
    # intervals completed by `stamp`, summed; an odometry edge's is the difference at its ends
    path_variance: float = 0.0


class EncoderStream:
    """Raw wheel positions in, clean cumulative wheel angles out.

    ``encoder_wrap`` and ``ticks_per_revolution`` are those of :class:`sclam_ros.core.params.SclamParams`
    (raw units; 0 = no wrap / positions already in radians). Rejected samples are counted in
    ``rejections`` under ``encoder_*`` reasons; segment starts are counted in
    ``segment_breaks`` by cause (``gap``, ``clock_jump_backward``, ``encoder_jump``).
    """

    def __init__(
        self,
        ticks_per_revolution: float = 0.0,
        encoder_wrap: float = 0.0,
        config: Optional[SyncConfig] = None,
        rejections: Optional[Rejections] = None,
    ):
        self.config = config or SyncConfig()
        self.rejections = rejections if rejections is not None else Rejections()
        self.segment_breaks: Counter = Counter()
        self._wrap = float(encoder_wrap)
        self._rad_per_unit = 2.0 * math.pi / ticks_per_revolution if ticks_per_revolution > 0 else 1.0
        # Parallel lists sorted by stamp; lists bisect in O(log n) and trim cheaply in bulk.
        self._stamps: list[float] = []
        self._left: list[float] = []
        self._right: list[float] = []
        self._segments: list[int] = []
        self._path: list[float] = []  # WheelAngles.path_variance at each sample
        self.segment = -1  # id of the current segment; -1 before the first sample
        self.segment_cause: dict[int, str] = {}
        self._last_raw: Optional[tuple[float, float]] = None
        self._last_stamp: Optional[float] = None
        self._periods: deque = deque(maxlen=self.config.period_sample)  # recent steps between samples
        self._steps_seen = 0
        self._gap_limit: Optional[float] = None  # max_gap from _periods, until judged again

    @property
    def max_gap(self) -> float:
        """The longest step between samples still interpolated across (see SyncConfig)."""
        if len(self._periods) < self.config.min_period_sample:
            return self.config.max_gap
        if self._gap_limit is None:  # a median per sample was 8 % of a batch run's time
            self._gap_limit = max(self.config.max_gap,
                                  self.config.gap_periods * float(np.median(self._periods)))
        return self._gap_limit

    @classmethod
    def from_params(cls, params, config=None, rejections=None) -> "EncoderStream":
        return cls(params.ticks_per_revolution, params.encoder_wrap, config, rejections)

    # --- input -------------------------------------------------------------------------
    def add(self, stamp: float, left_raw: float, right_raw: float) -> bool:
        """Feed one raw sample; True if it was kept."""
        if not (math.isfinite(stamp) and math.isfinite(left_raw) and math.isfinite(right_raw)):
            self.rejections.add("encoder_non_finite")
            return False
        cause = None  # why a new segment starts at this sample, if it does
        if self._last_stamp is not None:
            step = stamp - self._last_stamp
            if step == 0.0:
                self.rejections.add("encoder_duplicate_stamp")
                return False
            if step < 0.0:
                if -step <= self.config.clock_jump_backward:
                    self.rejections.add("encoder_non_monotonic")
                    return False
                # The clock went back: nothing before can be paired with what follows.
                self.clear()
                cause = "clock_jump_backward"
            else:
                if len(self._periods) < self.config.min_period_sample:  # the period is not known yet
                    limit = self.config.max_gap
                    if step <= self.config.max_first_period:
                        limit = max(limit, self.config.gap_periods
                                    * float(np.median([*self._periods, step])))
                else:
                    limit = self.max_gap
                if step > limit:
                    cause = "gap"
                # Every step counts toward the period, gaps too: the median ignores the rare
                # real gap, and a slow stream's first steps must teach the stream its rate.
                self._periods.append(step)
                # The limit follows the rate: judged again after every period_sample steps,
                # and at every step until the sample is full.
                self._steps_seen += 1
                sample = self.config.period_sample
                if self._steps_seen % sample == 0 or self._steps_seen <= sample:
                    self._gap_limit = None
        # The history holds unwrapped positions in raw units (integer tick counts stay exact
        # in a float64 up to 2^53); radians are produced on the way out.
        left, right = left_raw, right_raw
        if self._last_raw is None:
            self._start_segment(cause or "start")
        else:
            d_left = self._unwrap(left_raw - self._last_raw[0])
            d_right = self._unwrap(right_raw - self._last_raw[1])
            limit = self.config.max_wheel_speed * step + self.config.jump_margin
            if cause is None and max(abs(d_left), abs(d_right)) * self._rad_per_unit > limit:
                cause = "encoder_jump"
            if cause is None:
                left, right = self._left[-1] + d_left, self._right[-1] + d_right
            else:
                # New segment: angles restart from the raw reading; only differences
                # within a segment are ever used.
                self._start_segment(cause)
        self._append(stamp, left, right)
        self._last_raw = (left_raw, right_raw)
        self._last_stamp = stamp
        self._trim(stamp - self.config.max_history)
        return True

    def clear(self) -> None:
        """Forget the history (the next sample starts a new segment)."""
        self._stamps.clear()
        self._left.clear()
        self._right.clear()
        self._segments.clear()
        self._path.clear()
        self._last_raw = None
        self._last_stamp = None

    def discard_before(self, stamp: float) -> None:
        """Drop samples not needed to interpolate at ``stamp`` or later, nor to predict
        beyond the newest sample (keeps two at or before ``stamp``)."""
        self._trim(stamp, keep=2)

    # --- output ------------------------------------------------------------------------
    @property
    def latest_stamp(self) -> Optional[float]:
        return self._stamps[-1] if self._stamps else None

    @property
    def period(self) -> Optional[float]:
        """The median step between recent samples (s), once min_period_sample are known."""
        return float(np.median(self._periods)) if len(self._periods) >= self.config.min_period_sample else None

    def __len__(self) -> int:
        return len(self._stamps)

    def samples(self) -> list[EncoderSample]:
        """The clean samples currently held (cumulative rad, per segment)."""
        k = self._rad_per_unit
        return [EncoderSample(t, l * k, r * k) for t, l, r in zip(self._stamps, self._left, self._right)]

    def angles_between(self, t0: float, t1: float, segment: int) -> np.ndarray:
        """(k, 2) rad: the held samples of `segment` strictly between t0 and t1, at least
        config.min_arc apart and from both ends (the cuts of an edge's arcs)."""
        k = self._rad_per_unit
        out, last = [], t0
        lo, hi = bisect.bisect_right(self._stamps, t0), bisect.bisect_left(self._stamps, t1)
        for i in range(lo, hi):
            t = self._stamps[i]
            if self._segments[i] == segment and t - last >= self.config.min_arc \
                    and t1 - t >= self.config.min_arc:
                out.append((self._left[i] * k, self._right[i] * k))
                last = t
        return np.array(out, float).reshape(-1, 2)

    def wheel_angles_at(self, t: float) -> Optional[WheelAngles]:
        """Wheel angles at ``t`` by linear interpolation, or None where they are unknown."""
        return self.lookup(t)[0]

    def lookup(self, t: float) -> tuple[Optional[WheelAngles], Optional[str]]:
        """(WheelAngles, None), or (None, reason) when ``t`` is outside the history, in a gap,
        or across a segment break."""
        stamps = self._stamps
        if not stamps or t < stamps[0]:
            return None, "before_encoder_history"
        if t > stamps[-1]:
            return None, "after_encoder_history"
        i = bisect.bisect_right(stamps, t) - 1  # stamps[i] <= t
        if stamps[i] == t:
            angles = np.array([self._left[i], self._right[i]]) * self._rad_per_unit
            return WheelAngles(t, angles, self._segments[i], path_variance=self._path[i]), None
        if self._segments[i] != self._segments[i + 1]:
            return None, "in_encoder_gap"
        return self._on_line(i, t, curved=True), None

    def predict(self, t: float) -> Optional[WheelAngles]:
        """Wheel angles at ``t``: interpolated inside the history, extrapolated at the last
        two samples' speed a little beyond it (at most ``max_gap``), else None. For seeding
        a scan match before the encoders reach the scan, never for an odometry edge."""
        angles, reason = self.lookup(t)
        if angles is not None or reason != "after_encoder_history" or len(self._stamps) < 2:
            return angles
        if t - self._stamps[-1] > self.config.max_gap or self._segments[-1] != self._segments[-2]:
            return None
        return self._on_line(len(self._stamps) - 2, t)

    # --- internals -----------------------------------------------------------------------
    def _on_line(self, i: int, t: float, curved: bool = False) -> WheelAngles:
        """Wheel angles at ``t`` on the line through samples i and i + 1 (same segment), or
        with ``curved`` (between them, never beyond) on the parabola where _curved says so."""
        stamps = self._stamps
        w = (t - stamps[i]) / (stamps[i + 1] - stamps[i])
        angles = np.array([self._left[i] + w * (self._left[i + 1] - self._left[i]),
                           self._right[i] + w * (self._right[i + 1] - self._right[i])])
        off_line = self._off_line(i, t)
        if curved and self._curved(i):
            angles = angles - self._off_line_curved(i, t)
        variance = (self.config.interpolation_sigma_scale * off_line * self._rad_per_unit) ** 2
        return WheelAngles(t, angles * self._rad_per_unit, self._segments[i], variance,
                           t - stamps[i], self._path[i])

    def _off_line(self, i: int, t: float) -> np.ndarray:
        """(2,) raw units: how far below the line through samples i and i + 1 a wheel turning
        with angular acceleration a (_interval_motion) is at ``t``: a/2 · (t − t_i)(t_i+1 − t).
        Its magnitude, times config.interpolation_sigma_scale, is the interpolation's 1σ; it is also
        how far the parabola through samples i − 1, i and i + 1 lies below the line."""
        stamps = self._stamps
        return 0.5 * self._interval_motion(i)[1] * (t - stamps[i]) * (stamps[i + 1] - t)

    def _off_line_curved(self, i: int, t: float) -> np.ndarray:
        """(2,) raw units: how far below the line through samples i and i + 1 the cubic
        through samples i − 1 ... i + 2 lies at ``t``, or with no sample i + 2 in the
        segment (yet) the parabola through i − 1 ... i + 1 (_off_line).

        The cubic is the Hermite one (Catmull-Rom) that passes through samples i and i + 1
        with the slopes there of the parabolas through each of them and its two
        neighbours. It lies a(t)/2 · (t − t_i)(t_i+1 − t) below the line, a(t) the
        accelerations at the two samples (_interval_motion's, each from the two intervals
        beside its sample) interpolated linearly to t: exact for constant acceleration, and
        the same forwards and backwards in time. The parabola alone takes the acceleration
        at sample i for the whole interval and so lags the change of acceleration: on the
        way into a turn the heading lags, on the way out it leads, which does not cancel.
        The cubic through the four samples (exact for a constant change of acceleration)
        instead takes the slope at each sample from all four, and it errs at the samples
        themselves, where the odometry edges end (docs/decisions/slow_odometry.md, "The
        curve between samples").
        """
        if not self._cubic(i):
            return self._off_line(i, t)
        stamps = self._stamps
        start, end = stamps[i], stamps[i + 1]
        at_start, at_end = self._interval_motion(i)[1], self._interval_motion(i + 1)[1]
        w = (t - start) / (end - start)
        return 0.5 * (at_start + w * (at_end - at_start)) * (t - start) * (end - t)

    def _cubic(self, i: int) -> bool:
        """Whether samples i − 1 ... i + 2 are held and in one segment (_off_line_curved)."""
        segments = self._segments
        return (i > 0 and i + 2 < len(segments)
                and segments[i - 1] == segments[i] == segments[i + 1] == segments[i + 2])

    def settled(self, t: float) -> bool:
        """Whether the wheel angles at ``t`` (within the history) are final: no later
        sample will change them. On a curved interval (_curved) they are final once the
        sample after the interval's end has arrived (_off_line_curved then takes the cubic,
        or the parabola if that sample starts a new segment)."""
        stamps = self._stamps
        i = bisect.bisect_right(stamps, t) - 1
        if i < 0 or stamps[i] == t or i + 1 >= len(stamps):
            return True
        return i + 2 < len(stamps) or not self._curved(i)

    def _curved(self, i: int) -> bool:
        """Whether the angles between samples i and i + 1 are taken on a curve
        (_off_line_curved), not the line: the samples are further apart than
        config.curved_interval and sample i has one before it in its segment."""
        stamps = self._stamps
        return (stamps[i + 1] - stamps[i] > self.config.curved_interval
                and i > 0 and self._segments[i - 1] == self._segments[i])

    def _interval_motion(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        """(mean speed (2,), acceleration (2,)) of the wheels between samples i and i + 1, in
        raw units per s and per s². The acceleration is the change of mean speed since the
        interval before sample i (both known once sample i + 1 is, so online and batch
        agree); at a segment's first interval, from rest."""
        stamps = self._stamps
        period = stamps[i + 1] - stamps[i]
        speed = np.array([self._left[i + 1] - self._left[i],
                          self._right[i + 1] - self._right[i]]) / period
        if i > 0 and self._segments[i - 1] == self._segments[i]:
            before = stamps[i] - stamps[i - 1]
            previous = np.array([self._left[i] - self._left[i - 1],
                                 self._right[i] - self._right[i - 1]]) / before
            spacing = 0.5 * (before + period)
        else:
            previous, spacing = np.zeros(2), period
        return speed, (speed - previous) / spacing

    def _path_variance(self, i: int) -> float:
        """rad⁴: variance of where the robot ends up sideways at sample i + 1, against the
        constant-speed arc an odometry edge assumes between samples i and i + 1, in wheel
        units: times (r²/b)² it is m² (kinematics.motion_covariance).

        Ends that are samples make the edge's wheel angles, and so its rotation and length,
        exact, but not the shape of the path: a robot that turns, then drives, ends up
        beside one that drives, then turns. With wheel speeds w changing at a over the
        interval T (linearly) the end lies T³/12 · (a_v·ω − v·α) off the arc sideways,
        which in wheel speeds is (r²/b) · T³/12 · (a_l·w_r − a_r·w_l). Odometry edges
        composed through interpolated angles follow part of that path
        (core/config.py GraphConfig.composed_path_sigma_scale); one arc per interval, as
        ~/odom integrates, none of it.
        """
        stamps = self._stamps
        speed, acceleration = self._interval_motion(i)
        k = self._rad_per_unit
        offset = (self.config.interpolation_sigma_scale * (stamps[i + 1] - stamps[i]) ** 3 / 12.0
                  * abs(acceleration[0] * speed[1] - acceleration[1] * speed[0]) * k * k)
        return offset**2

    def _unwrap(self, delta: float) -> float:
        if self._wrap > 0.0:
            # Map the raw difference into [-wrap/2, wrap/2): exact for integer tick counts.
            half = 0.5 * self._wrap
            delta = (delta + half) % self._wrap - half
        return delta

    def _start_segment(self, cause: str) -> None:
        self.segment += 1
        self.segment_cause[self.segment] = cause
        if cause != "start":
            self.segment_breaks[cause] += 1
        # Keep the cause map bounded too: only segments still in the history matter.
        if len(self.segment_cause) > 64:
            oldest = self._segments[0] if self._segments else self.segment
            for sid in [s for s in self.segment_cause if s < oldest]:
                del self.segment_cause[sid]

    def _append(self, stamp: float, left: float, right: float) -> None:
        self._stamps.append(stamp)
        self._left.append(left)
        self._right.append(right)
        self._segments.append(self.segment)
        continued = len(self._stamps) > 1 and self._segments[-2] == self.segment
        self._path.append(self._path[-1] + self._path_variance(len(self._stamps) - 2)
                          if continued else 0.0)

    def _trim(self, stamp: float, keep: int = 1) -> None:
        # Keep the last `keep` samples at or before ``stamp`` so ``stamp`` itself stays
        # interpolable.
        k = bisect.bisect_right(self._stamps, stamp) - keep
        if k > 0:
            del self._stamps[:k], self._left[:k], self._right[:k], self._segments[:k], self._path[:k]

