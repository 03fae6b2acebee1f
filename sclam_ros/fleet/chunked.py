"""One long recording registered in time chunks on separate workers, joined into one graph.

Scan registration is sequential within a recording (each scan is matched against the local map
of the ones before it), and it is most of the cost. Cut in time, the chunks register
independently; each reads a few seconds before its own span (``LEAD_S``) so that its encoder
stream and its scan matcher are warm at its first kept scan. The joined keyframes are exactly
one per scan, numbered in stamp order:

  - the first kept keyframe of chunk k+1 was made by chunk k+1 after the margin scan that is
    chunk k's last kept keyframe (the same scan message), so its odometry increment and its
    scan match refer to that keyframe: the odometry and laser edges cross the boundary and the
    graph stays one connected chain;
  - where the margin did not produce that same scan (a gap in the data), the edge is dropped
    and counted (``chunk_boundary_unlinked``), never attached to the wrong node.

Every chunk after the first lays the decimation grid with the laser period measured on the
recording's first scans (``Chunk.scan_period``), so it matches the scans a sequential pass
matches; and it counts its messages, rejections and front-end report over its own span, so
the chunks' counts add up to the recording's. What differs from the sequential run is the
scan matcher's map, rebuilt at each chunk start: on the simulator the parameters stay
within a few hundredths of σ of it, on short real logs they moved by up to 1.5 σ
(docs/decisions/parallel.md).
"""
from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass, field

import numpy as np

from sclam_ros.core.inputs import Rejections

LEAD_S = 3.0  # s read before a chunk's span: encoder history and a warm scan-matcher map
# s read after it: the encoder samples that sync the span's last scans, two after each even
# at 1 Hz (between slow samples a scan waits for the second after it: sync.EncoderStream.settled)
TAIL_S = 2.5
MIN_CHUNK_S = 20.0  # shorter chunks spend more on their lead than they save


@dataclass(frozen=True)
class Chunk:
    """Keep the keyframes with scan stamps in [keep_from, keep_to); read [read_from, read_to);
    count the messages recorded in [span_from, span_to) (record time; None: open)."""

    number: int
    keep_from: float
    keep_to: float
    read_from: float
    read_to: float
    span_from: float = None
    span_to: float = None
    # s: the laser's period measured on the recording's first scans (None for the first
    # chunk, which measures it itself): every chunk matches the scans a sequential pass does
    scan_period: float = None


def plan_chunks(first: float, last: float, count: int, stamp_offset: float = 0.0,
                scan_period: float = None) -> list[Chunk]:
    """`count` chunks of equal length over the record-time span [first, last].

    ``stamp_offset`` is header stamp minus record time of the scans: the keep bounds are in
    header-stamp time (the keyframes' stamps), the read bounds in record time (the bag's).
    ``scan_period``: the laser's, from the recording's first scans, for the later chunks.
    The first chunk keeps everything before it and the last everything after it.
    """
    count = max(1, min(count, int((last - first) // MIN_CHUNK_S) or 1))
    bounds = np.linspace(first, last, count + 1)
    chunks = []
    for i in range(count):
        keep_from = -np.inf if i == 0 else bounds[i] + stamp_offset
        keep_to = np.inf if i == count - 1 else bounds[i + 1] + stamp_offset
        read_from = None if i == 0 else bounds[i] - LEAD_S
        read_to = None if i == count - 1 else bounds[i + 1] + TAIL_S
        span_from = None if i == 0 else float(bounds[i])
        span_to = None if i == count - 1 else float(bounds[i + 1])
        chunks.append(Chunk(i, float(keep_from), float(keep_to), read_from, read_to,
                            span_from, span_to, None if i == 0 else scan_period))
    return chunks


@dataclass
class ChunkResult:
    chunk: Chunk
    keyframes: list  # every keyframe the chunk made, with the chunk's own numbering
    rejections: Rejections
    messages: dict = field(default_factory=dict)  # bag.ReadCounts.as_dict of its span
    report: object = None  # its front end's FrontendReport
    wheel_sides: dict = None  # SideDisagreement.summary of its span (a skid-steer's)
    # (level, message) of what it logged: a worker's log does not reach the command's
    log_lines: list = field(default_factory=list)


class _Lines(logging.Handler):
    def __init__(self):
        super().__init__(logging.INFO)
        self.lines = []

    def emit(self, record):
        self.lines.append((record.levelno, record.getMessage()))


def register_chunk(path, params, chunk: Chunk, progress=None) -> ChunkResult:
    """Run the front end over the chunk's read window (a worker's task). What it logs is
    kept in the result (relog_chunks says it in the command's process), not printed."""
    from sclam_ros.io.recording import read_recording

    logger, lines = logging.getLogger("sclam"), _Lines()
    propagate, logger.propagate = logger.propagate, False
    logger.addHandler(lines)
    try:
        recording = read_recording(path, params, progress=progress, start=chunk.read_from,
                                   stop=chunk.read_to, counted=(chunk.span_from, chunk.span_to),
                                   scan_period=chunk.scan_period)
    finally:
        logger.removeHandler(lines)
        logger.propagate = propagate
    return ChunkResult(chunk, recording.keyframes, recording.rejections, recording.messages,
                       recording.report, recording.wheel_sides, lines.lines)


def relog_chunks(results: list[ChunkResult], logger=None) -> None:
    """Log what the chunks logged, in chunk order, each line once (every chunk warns about
    the same rejected topic or clock)."""
    logger = logger or logging.getLogger("sclam")
    seen = set()
    for result in sorted(results, key=lambda r: r.chunk.number):
        for level, message in result.log_lines:
            if message not in seen:
                seen.add(message)
                logger.log(level, "%s", message)


def join_chunks(results: list[ChunkResult]) -> tuple[list, Rejections]:
    """The chunks' kept keyframes renumbered into one chain (see the module docstring), and
    their rejections added: each chunk's are those of its own span (recording.SpanWatch),
    so they add up to a sequential pass's but for what a chunk's fresh map changes."""
    joined = []
    rejections = Rejections()
    global_index_of_stamp = {}
    for result in sorted(results, key=lambda r: r.chunk.number):
        rejections.counts.update(result.rejections.counts)
        chunk = result.chunk
        stamp_of_local = {kf.index: kf.stamp for kf in result.keyframes}
        for kf in result.keyframes:
            if not chunk.keep_from <= kf.stamp < chunk.keep_to:
                continue
            index = len(joined)
            linked = dataclasses.replace(kf, index=index)
            if kf.dphi is not None:
                previous = stamp_of_local.get(kf.index - 1)
                if not joined or previous != joined[-1].stamp:
                    linked.dphi = linked.dphi_parts = None
                    rejections.add("chunk_boundary_unlinked")
            if kf.laser_from is not None:
                source = global_index_of_stamp.get(stamp_of_local.get(kf.laser_from))
                if source is None:
                    linked.laser_from = linked.laser_motion = linked.laser_information = None
                    rejections.add("chunk_boundary_unlinked")
                else:
                    linked.laser_from = source
            global_index_of_stamp[kf.stamp] = index
            joined.append(linked)
    return joined, rejections


def joined_report(results: list[ChunkResult]):
    """One FrontendReport of the chunks: their counts summed (over the lead and tail too,
    as the rejections), the laser as the first chunk judged it on the recording's first
    scans, as a sequential run does."""
    from collections import Counter

    reports = [r.report for r in sorted(results, key=lambda r: r.chunk.number)]
    if not reports or any(r is None for r in reports):
        return None
    unconfirmed = Counter()
    for report in reports:
        unconfirmed.update(report.unconfirmed)
    return dataclasses.replace(
        reports[0], matches=sum(r.matches for r in reports), unconfirmed=dict(unconfirmed),
        odometry_guess_failures=sum(r.odometry_guess_failures for r in reports),
        odometry_guess_overruled=sum(r.odometry_guess_overruled for r in reports),
        skipped_scans=sum(r.skipped_scans for r in reports),
        matches_follow_samples=any(r.matches_follow_samples for r in reports))


def joined_messages(results: list[ChunkResult]) -> dict:
    """The chunks' message counts added: each counted its own span, so these are the
    recording's."""
    joined = {}
    for result in results:
        for topic, counts in result.messages.items():
            total = joined.setdefault(topic, dict.fromkeys(counts, 0))
            for key, n in counts.items():
                total[key] += n
    return dict(sorted(joined.items()))


def joined_wheel_sides(results: list[ChunkResult]):
    """The chunks' SideDisagreement summaries as one: stretches and those over the warning
    level added, the RMS over all stretches. None for one wheel a side."""
    summaries = [r.wheel_sides for r in results if r.wheel_sides]
    if not summaries:
        return None
    joined = {}
    for side, first in summaries[0].items():
        parts = [s[side] for s in summaries]
        stretches = sum(p["stretches"] for p in parts)
        squares = sum(p["rms_percent"] ** 2 * p["stretches"] for p in parts if p["stretches"])
        joined[side] = {"joints": first["joints"],
                        "rms_percent": float(np.sqrt(squares / stretches)) if stretches else None,
                        "stretches": stretches, "over": sum(p["over"] for p in parts)}
    return joined


def first_scans(path, params) -> tuple[float, float]:
    """(header stamp minus record time of the first scan, the laser's period as the front
    end's decimator measures it on the first scans: frontend/decimation.scan_period);
    (0, None) if the bag has no scan."""
    from sclam_ros.frontend.config import DecimationConfig
    from sclam_ros.frontend.decimation import scan_period
    from sclam_ros.io import bag
    from sclam_ros.io.messages import stamp_to_sec

    offset, stamps = 0.0, []
    messages = bag.iter_messages(path, [params.scan_topic])
    try:
        for _, record_time, msg in messages:
            stamps.append(stamp_to_sec(msg.header.stamp))
            offset = stamps[0] - record_time if len(stamps) == 1 else offset
            if len(stamps) > DecimationConfig().rate_sample:
                break
    finally:
        messages.close()
    if not stamps:
        return 0.0, None
    return offset, scan_period(stamps) if len(stamps) > DecimationConfig().rate_sample else None


def plan_for(path, params, chunks: int) -> list[Chunk]:
    """The chunks `path` is cut into for `chunks` workers (plan_chunks over its time span)."""
    from sclam_ros.io import bag

    first, last = bag.time_span(path)
    return plan_chunks(first, last, chunks, *first_scans(path, params))


def recording_of(results: list[ChunkResult]):
    """The io.recording.Recording the chunks make together (no front end: its report,
    message counts and wheel sides joined), after logging what they logged."""
    from sclam_ros.io.recording import Recording

    relog_chunks(results)
    keyframes, rejections = join_chunks(results)
    return Recording(keyframes, rejections, joined_messages(results),
                     wheel_sides=joined_wheel_sides(results), report=joined_report(results))


def dask_results(client, path, params, chunks: int, progress=None) -> list[ChunkResult]:
    """The chunks of `path` for `chunks` workers, registered on the Dask `client`."""
    from distributed import as_completed

    plan = plan_for(path, params, chunks)
    futures = client.map(register_chunk, [path] * len(plan), [params] * len(plan), plan,
                         pure=False)
    results = []
    for done, future in enumerate(as_completed(futures), 1):
        results.append(future.result())
        if progress is not None:
            progress(done, len(plan))
    return results


def register_in_chunks(client, path, params, chunks: int, progress=None):
    """Register `path` in `chunks` time chunks on the Dask `client`; (keyframes, rejections)."""
    return join_chunks(dask_results(client, path, params, chunks, progress))
