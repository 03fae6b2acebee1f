"""Encoder stream conditioning and wheel angles at scan stamps.

Two jobs, in the order the data flows:

1. :class:`EncoderStream` turns raw JointState wheel positions, fed one at a time, into a clean,
   bounded history of cumulative wheel angles (rad): counter wrap-around unwrapped, ticks
   converted to radians, bad samples rejected and counted, and the history cut into
   *segments* wherever it cannot be trusted to be continuous (a gap, a clock jump, an
   absurd jump of the counter). Wheel angles are interpolated only inside a segment.

2. :class:`ScanSynchronizer` holds each scan until the encoder stream covers its stamp, then
   emits it as a :class:`SyncedScan` with the wheel angles at that stamp. Increments between
   any two synced scans come from :func:`increment_between` (same segment required), and
   :func:`consecutive_increments` yields them for each consecutive pair.

Both work online (a node feeding messages as they arrive) and offline (a bag read in record
order) with the same code, and keep memory bounded.

Why interpolate: encoders (typ. 20–100 Hz) and the laser (typ. 10 Hz) are not synchronised;
taking the nearest encoder sample would put up to half an encoder period (0.5 cm at 1 m/s
and 100 Hz, more at 20 Hz) of timing error into every odometry edge, correlated with speed,
which the calibration would absorb into the wheel radii. Linear interpolation is exact for
constant wheel speed between two samples. Where the speed changes between samples it is
not, and on slow odometry (1-2 Hz) that error is larger than the wheels' slip noise and
biased with the drive (a 1 Hz wheel base came out 0.12 % short without slip noise): there
the angles are taken on a cubic through the two samples before and the two after the
stamp (SyncConfig.curved_interval; Catmull-Rom: exact for constant acceleration and
symmetric in time); a scan waits for the second sample after it (EncoderStream.settled).
Each
interpolated angle carries the variance of the line's interpolation error
(EncoderStream._off_line), which the odometry edges add to their covariance.
"""
from __future__ import annotations

import bisect
import math
from collections import Counter, deque
from dataclasses import dataclass, field
from typing import Iterable, Iterator, Optional

import numpy as np

from sclam_ros.core.inputs import EncoderSample, Rejections, Scan


PERIOD_SAMPLE = 20  # encoder steps the stream's own period is judged from
# The interpolation error's 1σ in units of its quadratic estimate (EncoderStream._off_line).
# The estimate takes the acceleration from the two intervals up to the next sample, so it
# lags a change of acceleration: on simulated PowerBot drives at 2 Hz (120 s, seed 1) the
# true errors' RMS was 1.19× the estimates' RMS (correlation 0.67-0.73 per wheel).
INTERPOLATION_SIGMA_SCALE = 1.2
MIN_PERIOD_SAMPLE = 3  # ... once it has seen at least this many


@dataclass
class SyncConfig:
    """Thresholds of the stream conditioning (s, rad/s, rad)."""

    # Longest interval between two encoder samples that is still interpolated across; a
    # longer silence starts a new segment (the counter may have wrapped more than once,
    # the robot may have been bumped, a driver restarted). 0.5 s is 10 periods at 20 Hz.
    # Odometry slower than that (a robot base reporting at 1-2 Hz) is judged by its own
    # rate instead: a gap is then more than gap_periods of its median period.
    max_gap: float = 0.5
    gap_periods: float = 5.0
    # Before the stream knows its period (its first MIN_PERIOD_SAMPLE steps), a step up to
    # this long is judged against the steps seen so far, itself included, so that a 1-2 Hz
    # base loses none of its first seconds; a longer first step (a stale first message)
    # is a gap whatever the rate turns out to be.
    max_first_period: float = 2.0
    # A stamp earlier than the newest one by more than this is a clock jump (a bag played in
    # a loop, a clock set back): the history is dropped and a new segment starts. Smaller
    # steps back are single out-of-order samples and are rejected.
    clock_jump_backward: float = 1.0
    # An increment larger than max_wheel_speed·dt + jump_margin is not physical (a counter
    # reset, a driver restart, a corrupted value): a new segment starts at that sample
    # instead of letting the jump into an odometry edge. 60 rad/s is 6 m/s on a 0.1 m wheel.
    max_wheel_speed: float = 60.0
    jump_margin: float = 0.5
    # History kept behind the newest sample, so memory stays bounded online; the
    # synchroniser also trims what no pending scan can need.
    max_history: float = 10.0
    # How long (in scan time) a scan waits for the encoder stream to reach its stamp.
    max_scan_latency: float = 1.0
    # Between samples further apart than this, the angles are interpolated on a curve
    # (EncoderStream._curved): a cubic through the two samples before and the two after
    # the stamp, or the parabola through the one before and the two around it where no
    # second sample follows in the segment (_off_line_curved), not on the straight line.
    # Measured on simulated 1 Hz drives (`python bench/sensor_matrix.py --seeds 20
    # --duration 120 --rows 7`; ad hoc on the same recordings without slip noise, where
    # only the interpolation errs): wheel base −0.12 ± 0.02 % on the line, −0.05 ± 0.01 %
    # on the parabola.
    # Closer samples keep the line: there the interpolation error is below the slip noise,
    # and the second difference of ticks a few ms apart is mostly quantisation and stamp
    # jitter.
    curved_interval: float = 0.3


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
        self._periods: deque = deque(maxlen=PERIOD_SAMPLE)  # recent steps between samples
        self._steps_seen = 0
        self._gap_limit: Optional[float] = None  # max_gap from _periods, until judged again

    @property
    def max_gap(self) -> float:
        """The longest step between samples still interpolated across (see SyncConfig)."""
        if len(self._periods) < MIN_PERIOD_SAMPLE:
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
                if len(self._periods) < MIN_PERIOD_SAMPLE:  # the period is not known yet
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
                # The limit follows the rate: judged again after every PERIOD_SAMPLE steps,
                # and at every step until the sample is full.
                self._steps_seen += 1
                if self._steps_seen % PERIOD_SAMPLE == 0 or self._steps_seen <= PERIOD_SAMPLE:
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
        """The median step between recent samples (s), once MIN_PERIOD_SAMPLE are known."""
        return float(np.median(self._periods)) if len(self._periods) >= MIN_PERIOD_SAMPLE else None

    def __len__(self) -> int:
        return len(self._stamps)

    def samples(self) -> list[EncoderSample]:
        """The clean samples currently held (cumulative rad, per segment)."""
        k = self._rad_per_unit
        return [EncoderSample(t, l * k, r * k) for t, l, r in zip(self._stamps, self._left, self._right)]

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
        variance = (INTERPOLATION_SIGMA_SCALE * off_line * self._rad_per_unit) ** 2
        return WheelAngles(t, angles * self._rad_per_unit, self._segments[i], variance,
                           t - stamps[i], self._path[i])

    def _off_line(self, i: int, t: float) -> np.ndarray:
        """(2,) raw units: how far below the line through samples i and i + 1 a wheel turning
        with angular acceleration a (_interval_motion) is at ``t``: a/2 · (t − t_i)(t_i+1 − t).
        Its magnitude, times INTERPOLATION_SIGMA_SCALE, is the interpolation's 1σ; it is also
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
        themselves, where the odometry edges end. Measured ad hoc on 10 simulated PowerBot
        drives at 1 Hz without wheel slip (120 s, 1200 edges, true calibration), the
        edges' sideways error against their rotation and their rotation's error against
        the rotation: parabola +2.1 ± 0.3 mm/rad and −0.0 ± 0.1 ‰; cubic through four
        samples −0.2 ± 0.3 mm/rad and +0.5 ± 0.1 ‰; Catmull-Rom −0.2 ± 0.3 mm/rad and
        −0.0 ± 0.1 ‰ (sideways RMS 3.3, 2.8, 2.8 mm).
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
        (graph.COMPOSED_PATH_SIGMA_SCALE); one arc per interval, as ~/odom integrates,
        none of it.
        """
        stamps = self._stamps
        speed, acceleration = self._interval_motion(i)
        k = self._rad_per_unit
        offset = (INTERPOLATION_SIGMA_SCALE * (stamps[i + 1] - stamps[i]) ** 3 / 12.0
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


@dataclass
class SyncedScan:
    """A scan with the wheel angles at its stamp. ``index`` counts synced scans from 0."""

    index: int
    scan: Scan
    wheels: WheelAngles


@dataclass
class WheelIncrement:
    """Wheel angle increments between two synced scans: u = (dφ_l, dφ_r) in rad over dt s."""

    index_from: int
    index_to: int
    stamp_from: float
    stamp_to: float
    dphi: np.ndarray  # (2,) rad

    @property
    def dt(self) -> float:
        return self.stamp_to - self.stamp_from


def increment_between(
    a: SyncedScan, b: SyncedScan, stream: Optional[EncoderStream] = None
) -> tuple[Optional[WheelIncrement], Optional[str]]:
    """(increment from a to b, None), or (None, reason) when the encoders do not bridge them.

    The reason names the cause of the segment break when ``stream`` is given
    (``increment_across_gap``, ``increment_across_clock_jump_backward``, ...).
    """
    if b.wheels.segment != a.wheels.segment:
        cause = "segment_break"
        if stream is not None:
            cause = stream.segment_cause.get(b.wheels.segment, cause)
        return None, f"increment_across_{cause}"
    if b.scan.stamp <= a.scan.stamp:
        return None, "increment_non_monotonic"
    return (
        WheelIncrement(a.index, b.index, a.scan.stamp, b.scan.stamp, b.wheels.angles - a.wheels.angles),
        None,
    )


class ScanSynchronizer:
    """Pairs scans with the encoder stream, online or over a bag in record order.

    Feed JointState samples with :meth:`add_encoder` and scans with :meth:`add_scan`, in the
    order they arrive; each returns the scans that became ready (a list of SyncedScan, in
    stamp order). Call :meth:`flush` at the end of a bag. Scans that can never be synced
    are counted in ``rejections`` (``scan_*`` reasons).
    """

    def __init__(self, stream: EncoderStream, rejections: Optional[Rejections] = None):
        self.stream = stream
        self.config = stream.config
        self.rejections = rejections if rejections is not None else stream.rejections
        self._pending: list[Scan] = []
        self._last_scan_stamp: Optional[float] = None
        self._next_index = 0
        self._stream_resets = 0

    def add_encoder(self, stamp: float, left_raw: float, right_raw: float) -> list[SyncedScan]:
        self.stream.add(stamp, left_raw, right_raw)
        resets = self.stream.segment_breaks["clock_jump_backward"]
        if resets != self._stream_resets:
            # The encoder clock went back: scans waiting for the old time line never resolve.
            self._stream_resets = resets
            self._drop_pending("scan_dropped_at_clock_jump")
        return self._resolve()

    def add_scan(self, scan: Scan) -> list[SyncedScan]:
        last = self._last_scan_stamp
        if not math.isfinite(scan.stamp):
            self.rejections.add("scan_non_finite_stamp")
            return []
        if last is not None:
            if scan.stamp == last:
                self.rejections.add("scan_duplicate_stamp")
                return []
            if scan.stamp < last:
                if last - scan.stamp <= self.config.clock_jump_backward:
                    self.rejections.add("scan_non_monotonic")
                    return []
                self._drop_pending("scan_dropped_at_clock_jump")
        self._last_scan_stamp = scan.stamp
        self._pending.append(scan)
        return self._resolve()

    @property
    def pending(self) -> tuple:
        """The scans waiting for the encoders to reach their stamp, oldest first."""
        return tuple(self._pending)

    def flush(self) -> list[SyncedScan]:
        """End of data: sync what can be, count the rest."""
        ready = self._resolve(final=True)
        self._drop_pending("scan_no_encoder_coverage")
        return ready

    def _resolve(self, final: bool = False) -> list[SyncedScan]:
        """The pending scans the encoders cover, in order; with ``final`` (end of data)
        also those whose angles more samples would still have settled."""
        ready = []
        latest = self.stream.latest_stamp
        newest_scan = self._last_scan_stamp
        while self._pending:
            scan = self._pending[0]
            covered = latest is not None and scan.stamp <= latest
            if not (covered and (final or self.stream.settled(scan.stamp))):
                # Slow odometry (1-2 Hz) may take up to its gap allowance to cover a scan,
                # and one period more to settle it (EncoderStream.settled).
                wait = max(self.config.max_scan_latency, self.stream.max_gap)
                if newest_scan - scan.stamp <= wait:
                    break  # wait for more encoder samples; later scans wait behind it
                if not covered:
                    self._pending.pop(0)
                    self.rejections.add("scan_no_encoder_coverage")
                    continue
                # covered but unsettled for too long: synced with the samples at hand
            self._pending.pop(0)
            wheels, reason = self.stream.lookup(scan.stamp)
            if wheels is None:
                self.rejections.add(f"scan_{reason}")
                continue
            ready.append(SyncedScan(self._next_index, scan, wheels))
            self._next_index += 1
        # Nothing older than the oldest pending scan (or the newest scan) is needed any more.
        horizon = self._pending[0].stamp if self._pending else newest_scan
        if horizon is not None:
            self.stream.discard_before(horizon)
        return ready

    def _drop_pending(self, reason: str) -> None:
        if self._pending:
            self.rejections.add(reason, len(self._pending))
            self._pending.clear()


def consecutive_increments(
    synced: Iterable[SyncedScan],
    stream: Optional[EncoderStream] = None,
    rejections: Optional[Rejections] = None,
) -> Iterator[WheelIncrement]:
    """Wheel increments of each consecutive pair of synced scans; pairs that the encoders do
    not bridge are counted in ``rejections`` and skipped."""
    previous = None
    for item in synced:
        if previous is not None:
            inc, reason = increment_between(previous, item, stream)
            if inc is not None:
                yield inc
            elif rejections is not None:
                rejections.add(reason)
        previous = item
