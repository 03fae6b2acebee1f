"""A noisy laser's walls: its scan cut into straight segments, each one's line fitted on ranges.

The point-to-line refinement measures a new scan's points against the reference scan's
wall lines. On a laser with centimetres of range noise a line fitted over a few beams is
off by tens of degrees, and one fitted over a fixed stretch of wall around each return
bends at corners and openings, where its neighbourhood takes in the other wall, and is
turned by the noise itself: a return's noise lies along its beam, so its shifts across
and along the wall are correlated, and a least-squares line through the points leans
toward the beams. Both move the lines the motion is measured from, by amounts that do not
average out over a recording.

Here each piece of the scan between breakpoints is split where it stops being straight
(near the return farthest from the chord between its ends, where two lines fit it best),
and each straight segment's line is the least-squares fit of its returns' *ranges* (their
bearings are exact: range noise is the only noise), which is the line the returns measure
without the lean. A return's residual origin (anchor) is where its own beam meets that
line: a point of the wall as the noise-free beam would have hit it, so neither which
reference return a new point is paired with nor whether it lies clear of the range limit
depends on that return's noise.

Tuning: WallSegmentsConfig (frontend/config.py). Why these lines: docs/decisions/
point_to_line.md, "A noisy laser's lines: whole wall segments, fitted on ranges".
"""
from __future__ import annotations

import math

import numpy as np

from sclam_ros.frontend.config import WallSegmentsConfig


def scan_pieces(points, margin, config: WallSegmentsConfig = WallSegmentsConfig()):
    """(pieces, closed): index arrays (beam order, each contiguous around the scan) of the
    pieces of the scan `points` (N, 2) between breakpoints, where consecutive returns are
    config.breakpoint_incidence or more apart in bearing (dropouts, a field of view's ends)
    or farther apart than a surface at that incidence allows plus `margin` (m): the
    adaptive breakpoint detector (Borges & Aldon 2004). A full turn's last and first
    returns are consecutive too: a surface across the seam is one piece. closed: no
    breakpoint at all (one surface around the laser), then one piece."""
    order, starts, closed = piece_bounds(points, margin, config)
    return np.split(order, starts[1:]), closed


def piece_bounds(points, margin, config: WallSegmentsConfig = WallSegmentsConfig()):
    """(order, starts, closed) of scan_pieces: the returns' indices rolled so that the first
    piece starts at 0, and where each piece starts in them (the pieces are runs of it)."""
    incidence = config.breakpoint_incidence
    n = len(points)
    bearing = np.arctan2(points[:, 1], points[:, 0])
    ranges = np.hypot(points[:, 0], points[:, 1])
    following = np.roll(np.arange(n), -1)  # the last return's successor is the first
    dphi = np.abs(np.angle(np.exp(1j * (bearing[following] - bearing))))
    near = dphi < incidence
    reach = (np.minimum(ranges, ranges[following]) * np.sin(dphi)
             / np.sin(np.where(near, incidence - dphi, 1.0)))
    cut = ~near | (np.hypot(*(points[following] - points).T) > reach + margin)
    if not cut.any():
        return np.arange(n), np.zeros(1, int), True
    # Pieces start after each cut; rolled so that the first piece starts after the first cut.
    start = int(np.argmax(cut)) + 1
    order = np.roll(np.arange(n), -start)
    return order, np.concatenate(([0], np.flatnonzero(cut[order][:-1]) + 1)), False


def wall_lines(points, noise, usable_range=np.inf, growth=0.0,
               config: WallSegmentsConfig = WallSegmentsConfig()):
    """(normals (N, 2), anchors (N, 2), keep (N,) bool) of a noisy laser's returns `points`
    (N, 2, beam order) with range noise `noise` (m), growing with range as 1 + growth·r
    (growth in 1/m; the fits weigh each return by 1/σ²): each kept return's wall line (its
    normal, and where the return's beam meets it). Returns on no straight segment are not
    kept (their normal is zero and their anchor the return itself), nor are those at a
    grazing incidence to their line, whose anchor lies beyond `usable_range` (m), or that
    lie near a corner within the noise of the other wall's line."""
    n = len(points)
    normals = np.zeros_like(points)
    anchors = points.copy()
    keep = np.zeros(n, bool)
    segment_of = np.full(n, -1)  # index in `lines` of each return's segment
    lines = []  # (normal, distance, the segment's returns)
    for segment in straight_segments(points, noise, config):
        line = _line_on_ranges(points[segment], noise, growth, config)
        if line is None:
            continue
        normal, distance = line
        segment_of[segment] = len(lines)
        lines.append((normal, distance, segment))
        beams = points[segment] / np.hypot(points[segment, 0], points[segment, 1])[:, None]
        cos_incidence = beams @ normal
        met = cos_incidence >= config.min_cos_incidence
        anchor = beams * (distance / np.where(met, cos_incidence, 1.0))[:, None]
        normals[segment] = normal
        anchors[segment] = np.where(met[:, None], anchor, points[segment])
        keep[segment] = met & (np.hypot(anchor[:, 0], anchor[:, 1]) <= usable_range)
    # Near a corner a return within the noise of the other wall's line may be either wall's
    # (the split is a least-squares guess): from each end of a segment that meets another
    # at a corner (their lines config.corner or more apart in direction; a wall split in two
    # by an outlier is not one), the returns within config.ambiguous times the noise of the
    # other's line are not kept, up to the first that is clear of it.
    for index, (normal, _, segment) in enumerate(lines):
        ends = (((segment[0] - 1) % n, segment), ((segment[-1] + 1) % n, segment[::-1]))
        for outside, inward in ends:  # the return just outside an end, the segment from it
            other = segment_of[outside]
            if other < 0 or other == index:
                continue
            other_normal, other_distance, _ = lines[other]
            if abs(other_normal @ normal) > math.cos(config.corner):
                continue
            close = (np.abs(points[inward] @ other_normal - other_distance)
                     < config.ambiguous * noise)
            keep[inward[:len(close) if close.all() else int(np.argmin(close))]] = False
    return normals, anchors, keep


def straight_segments(points, noise, config: WallSegmentsConfig = WallSegmentsConfig()):
    """Index arrays (beam order) of the scan's straight segments of at least
    config.min_segment_returns returns: each piece between breakpoints (with a margin of
    config.break_noise times the range noise `noise`) that is not straight (_straight) is
    split in two (_split_point) until it is."""
    segments = []
    pending, closed = scan_pieces(points, config.break_noise * noise, config)
    while pending:
        piece = pending.pop()
        if len(piece) < config.min_segment_returns:
            continue
        if _straight(points[piece], noise, config):
            segments.append(piece)
            continue
        at = _split_point(points[piece], config.split_reach)
        pending += [piece[:at], piece[at:]]
    if closed and len(segments) > 1:
        # One surface around the laser was cut at the scan's seam, which is no corner: the
        # segments on either side of it are one wall where together they are straight.
        # (Either side may have been too short to be a segment.)
        last = next((i for i, seg in enumerate(segments) if seg[-1] == len(points) - 1), None)
        first = next((i for i, seg in enumerate(segments) if seg[0] == 0), None)
        if None not in (first, last) and first != last:
            joined = np.concatenate([segments[last], segments[first]])
            if _straight(points[joined], noise, config):
                segments = [seg for i, seg in enumerate(segments)
                            if i not in (first, last)] + [joined]
    return segments


def _straight(p, noise, config: WallSegmentsConfig):
    """Whether the returns p (n, 2) lie on one line within the range noise: their RMS
    distance from it within config.straight_spread times the noise and the farthest's within
    config.split_deviation times."""
    normal, centre, across, _ = _total_least_squares(p)
    return (across <= config.straight_spread * noise
            and np.abs((p - centre) @ normal).max() <= config.split_deviation * noise)


def _split_point(p, split_reach):
    """k where p (a piece that is not straight, n ≥ 10 returns) is split into p[:k] and
    p[k:]: near the return farthest from the chord between its ends (each end the mean of
    three returns, so that one return's noise does not turn the chord; on a piece whose
    ends meet, farthest from them), which finds a corner among several, then where, within
    split_reach × n returns of it, the two sides' lines leave the smallest sum of squared
    distances: at a corner, the corner to within the noise (the farthest return alone
    lands a few returns off often enough to give one wall's line to the other's returns)."""
    n = len(p)
    first, last = p[:3].mean(axis=0), p[-3:].mean(axis=0)
    chord = last - first
    length = math.hypot(*chord)
    if length > 0.1 * np.ptp(p, axis=0).max():
        farthest = int(np.argmax(np.abs((p - first) @ (np.array([-chord[1], chord[0]]) / length))))
    else:
        farthest = int(np.argmax(np.hypot(*(p - 0.5 * (p[0] + p[-1])).T)))
    # The lines are fitted within split_reach of that return on either side alike, so that
    # the scan read backwards (the same scene mirrored) is split alike and another corner
    # farther along does not take part.
    reach = max(3, int(split_reach * n))
    low = max(0, min(farthest - reach + 1, n - 2 * reach))  # 2·reach returns near an end
    high = min(n, max(farthest + reach + 1, 2 * reach))
    q = p[low:high] - p[low:high].mean(axis=0)  # centred for the sums' precision
    moments = np.column_stack([np.ones(len(q)), q[:, 0], q[:, 1], q[:, 0] ** 2, q[:, 1] ** 2,
                               q[:, 0] * q[:, 1]])
    before = np.cumsum(moments, axis=0)[:-1]  # row k − 1: the sums over q[:k]
    after = before[-1] + moments[-1] - before
    k = np.arange(2, len(q) - 1)  # each side at least two returns
    return low + int(k[np.argmin(_residual_sum(before[k - 1]) + _residual_sum(after[k - 1]))])


def _residual_sum(sums):
    """Sum of squared distances of a set of points from their total-least-squares line, from
    their moments' sums (count, Σx, Σy, Σx², Σy², Σxy) (…, 6): the smaller eigenvalue of
    their scatter matrix."""
    count, sx, sy, sxx, syy, sxy = np.moveaxis(sums, -1, 0)
    cxx, cyy, cxy = sxx - sx * sx / count, syy - sy * sy / count, sxy - sx * sy / count
    return np.maximum(0.5 * (cxx + cyy) - np.hypot(0.5 * (cxx - cyy), cxy), 0.0)


def _total_least_squares(p):
    """(normal, centroid, RMS spread across, RMS spread along) of the line through p (n, 2)."""
    centre = p.mean(axis=0)
    d = p - centre
    spreads, axes = np.linalg.eigh(d.T @ d / len(p))
    return (axes[:, 0], centre, math.sqrt(max(spreads[0], 0.0)),
            math.sqrt(max(spreads[1], 0.0)))


def _line_on_ranges(p, noise, growth, config: WallSegmentsConfig):
    """(normal, distance from the laser) of the wall line n·x = distance through a straight
    segment's returns p (n, 2), fitted on their ranges, or None where the segment is
    shorter than config.min_segment_length or the fit fails. Returns more than 3σ off the
    total-least-squares line are left out (a neighbouring surface's last return)."""
    normal, centre, _, along = _total_least_squares(p)
    inliers = np.abs((p - centre) @ normal) <= 3.0 * noise
    if inliers.sum() >= config.min_segment_returns and not inliers.all():
        p = p[inliers]
        normal, centre, _, along = _total_least_squares(p)
    if along * math.sqrt(12.0) < config.min_segment_length:  # a uniform stretch of L: L/√12
        return None
    return _fit_on_ranges(p, normal, centre, growth, config)


def _fit_on_ranges(p, normal, centre, growth, config: WallSegmentsConfig):
    """(normal, distance) minimising Σ w_i (r_i − distance / cos(φ_i − θ))² over the returns'
    ranges r_i and bearings φ_i, θ the normal's angle, w_i = 1/(1 + growth·ρ_i)² (1/σ² of
    a range noise that grows with range, wall_lines; ρ_i = distance / cos(φ_i − θ), where
    the beam meets the line): Gauss-Newton from the
    total-least-squares line (normal, centre), at most config.range_fit_iterations steps.
    Beams that meet that line more glancingly than config.min_cos_incidence are left out of
    the fit (a small turn of the line moves their predicted range by metres); None if fewer
    than config.min_segment_returns are left."""
    if centre @ normal < 0.0:
        normal = -normal  # pointing away from the laser: distance > 0
    bearing = np.arctan2(p[:, 1], p[:, 0])
    ranges = np.hypot(p[:, 0], p[:, 1])
    theta, distance = math.atan2(normal[1], normal[0]), float(centre @ normal)
    fitted = np.cos(bearing - theta) >= config.min_cos_incidence
    if fitted.sum() < config.min_segment_returns:
        return None
    bearing, ranges = bearing[fitted], ranges[fitted]
    for _ in range(config.range_fit_iterations):
        incidence = bearing - theta
        cos = np.cos(incidence)
        if np.any(cos < 0.5 * config.min_cos_incidence):
            return None  # the fit turned the line onto a beam: not a wall these returns fix
        # Each return's weight from the range its beam meets the line at, not its measured
        # range: weighed by the latter, the returns its noise brought nearer would weigh
        # more and pull the line toward the laser.
        weight = 1.0 / (1.0 + growth * distance / cos) ** 2
        residual = ranges - distance / cos
        jacobian = np.column_stack([-1.0 / cos, distance * np.sin(incidence) / cos ** 2])
        try:
            step = np.linalg.solve(jacobian.T @ (weight[:, None] * jacobian),
                                   -jacobian.T @ (weight * residual))
        except np.linalg.LinAlgError:
            return None
        distance, theta = distance + step[0], theta + step[1]
        if abs(step[0]) < 1e-7 and abs(step[1]) < 1e-9:
            break
    return np.array([math.cos(theta), math.sin(theta)]), distance
