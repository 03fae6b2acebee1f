"""Scan/encoder synchronisation: each scan with the wheel angles at its stamp.

:class:`ScanSynchronizer` holds each scan until the encoder stream
(frontend/encoder_stream.py) covers its stamp, then emits it as a :class:`SyncedScan` with
the wheel angles at that stamp. Increments between any two synced scans come from
:func:`increment_between` (same segment required), and :func:`consecutive_increments`
yields them for each consecutive pair. Online (a node feeding messages as they arrive) and
offline (a bag read in record order) use the same code; memory stays bounded.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Iterable, Iterator, Optional

import numpy as np

from sclam_ros.core.inputs import Rejections, Scan
from sclam_ros.frontend.encoder_stream import EncoderStream, WheelAngles


@dataclass
class SyncedScan:
    """A scan with the wheel angles at its stamp. ``index`` counts synced scans from 0."""

    index: int
    scan: Scan
    wheels: WheelAngles
    # (k, 2) rad: encoder samples since the previous synced scan of the same segment, the
    # cuts between its odometry arcs (EncoderStream.angles_between; empty: one arc)
    between: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))


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
        self._last_synced: Optional[WheelAngles] = None

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
            previous = self._last_synced
            between = (self.stream.angles_between(previous.stamp, wheels.stamp, wheels.segment)
                       if previous is not None and previous.segment == wheels.segment
                       else np.zeros((0, 2)))
            ready.append(SyncedScan(self._next_index, scan, wheels, between))
            self._last_synced = wheels
            self._next_index += 1
        # Nothing older than the oldest pending scan (or the newest scan) is needed any
        # more, nor older than the last synced scan: the samples since it cut the next
        # edge's arcs.
        horizon = self._pending[0].stamp if self._pending else newest_scan
        if horizon is not None and self._last_synced is not None:
            horizon = min(horizon, self._last_synced.stamp)
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
