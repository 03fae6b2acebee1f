"""The reference scan of a match: its returns on lines, each with the line's normal and the
point residuals are measured from, ready for pairing with a new scan's points.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from sclam_ros.frontend.laser_noise import NOISY_RANGE
from sclam_ros.frontend.wall_segments import scan_pieces, wall_lines

NORMAL_NEIGHBOURS = 6
# A noisy laser's lines (NOISY_RANGE) are its walls' whole straight segments instead, fitted
# on the returns' ranges, each return's residual origin (anchor) where its beam meets its
# segment's line (frontend/wall_segments.py). Six beams of a 3 cm laser span a few cm of
# wall: their line is off by tens of degrees (test_point_to_line), which lets the along-wall
# offsets of nearest-sample pairing (the point-to-point bias this refinement removes) back
# into the motion; paired with the nearest noisy return and measured from it, a residual
# shrinks wherever the new scan already is, and the match stays near its start.
# Measured with `python bench/sensor_matrix.py --rows 2 3 4 10 11 --seeds 80 --duration
# 120` (paired seeds), against lines fitted over 0.25 m of wall around each return with
# their centroids as anchors (RMS errors in parentheses): corridors scene, URG-04LX-like radii
# and base +0.185 / +0.190 / +0.209 → +0.034 / +0.048 / +0.043 % (0.25 / 0.26 / 0.37 →
# 0.15 / 0.14 / 0.30 %), low-cost +0.18 / +0.18 / +0.19 → +0.04 / −0.01 / +0.01 % (0.39 /
# 0.40 / 0.49 → 0.25 / 0.25 / 0.41 %); office, low-cost +0.078 / +0.073 / +0.007 → +0.067 /
MAX_PAIR_DISTANCE = 0.15  # m; KISS-ICP's answer is within a few cm
# ALONG_LINE: on a reference whose returns are their own residual origins (lines fitted over
# NORMAL_NEIGHBOURS beams), a new point is paired with its nearest return when it lies in an
# ellipse around it: MAX_PAIR_DISTANCE across the return's line and ALONG_REACH times the
# beams' spacing on the surface there along it (at least MAX_PAIR_DISTANCE, at most
# ALONG_CAP; the spacing at grazing incidence taken as at MIN_COS_INCIDENCE). Within a
# circle of MAX_PAIR_DISTANCE instead, where the beams are sparse on the surface whether a
# point between two returns reaches one depends on that return's own range noise: the pairs
# are chosen by the noise of the points their residuals are measured from, and outdoors
# (parked cars' sides 5-15 m away, beams 30 cm and more apart on them) the matches came out
# long. `python bench/sensor_matrix.py --seeds 80 --duration 120` (paired seeds), circle →
# ellipse: outdoors radii and base +0.080 / +0.067 / +0.047 → +0.025 / +0.013 / −0.013 %
# (± 0.02 / 0.02 / 0.05), match scale 1.0007 → 0.9995, laser x / y RMS 3.5 / 4.1 → 3.1 /
# 3.5 mm; the indoor rows on 1 cm lasers move by 0.001 % at most. A noisy laser's anchors
# lie on whole segments' lines, not at single returns (wall_segments): it keeps the circle.
ALONG_REACH = 0.6
ALONG_CAP = 1.0  # m
MIN_COS_INCIDENCE = 0.2
MAX_LINE_SPREAD = 0.02  # m RMS off the fitted line: beyond it the neighbourhood is a corner
# A driver reports nothing where the measured range exceeds the laser's range_max, so of a
# wall near the limit only the returns whose noise brought them nearer are kept: its points
# sit nearer than the wall, by more the closer the wall is to the limit. A laser with a
# narrow field of view sees mostly walls ahead, which the earlier (reference) scan of a pair
# sees farther than the later one: the reference's wall is too near and the motion toward
# it comes out short. `python bench/range_limit_bias.py` (URG-04LX-like straight-driving
# pairs, the same noise draws in every variant): leaving out the reference's returns whose
# true range is within 4σ of the limit lengthens the matches by 0.14 ± 0.02 %. The true
# range is unknown, and leaving out returns by their measured range is the same cut again
# (bench/refinement_bias.py: −0.24 % with those within 3σ of the limit left out, against
# −0.14 %). What is left out instead is a pair whose reference wall line (its anchor: on
# a noisy laser where the return's beam meets its segment's line, else the return) lies
# within CLEAR_OF_LIMIT times the laser's range noise of the limit, from either scan: on
# those pairs +0.02 ± 0.01 %; in the calibrations (bench/sensor_matrix.py --seeds 20) radii
# −0.10 / −0.14 → −0.08 / −0.11 %, base −0.04 → −0.01 %, match scale 0.9986 → 0.9995.
# Wider margins (3σ + 0.25 m, + 0.5 m) and testing the new point's own range, or its beam's
# range to the reference line, did no better (measured ad hoc on the same kind of pairs).
# Which lines are clear of the limit is judged as BY_NEIGHBOURS says: on a noisy laser by
# the anchor (where the noise-free beam would have hit the fitted line), else by the
# return's neighbours' median range.
CLEAR_OF_LIMIT = 3.0
# BY_NEIGHBOURS: whether a reference return is used is decided from its neighbours in beam
# order, the return itself left out, never from where its own noise put it. Decisions taken
# from the return's own position choose it for its noise, and the origins the refinement
# then measures from sit off the walls (`python bench/reference_bias.py`, offsets along the
# line's normal against the simulator's walls). Judged by its own range whether a return is
# clear of the range limit is the driver's cut again; judged by the median range of its
# neighbours (_neighbours_within) it is not (test_point_to_line's range-limit test).
# (A noisy laser's anchors are where its beams meet their segments' lines: nothing about
# them depends on a return's own noise but through the fit of its whole segment.)
# SMALL_OBJECT: on a laser whose lines are fitted over NORMAL_NEIGHBOURS beams, a return on
# an object narrower than this (a tree trunk, a pole) gets no line where the laser's
# measured range noise is SMALL_OBJECT_NOISE or more. Six beams on such an object span its
# corners, and whether their spread passes MAX_LINE_SPREAD is then decided by the returns'
# own noise (its share of six returns' spread is about 0.9σ: 9 mm of the 20 at 1 cm): the
# lines kept there are chosen for their noise (as BY_NEIGHBOURS describes), and the
# matches built on them come out turned. Objects are the pieces of the scan between
# breakpoints (_object_extent), their extent the diagonal of the box around them.
# Measured with `python bench/sensor_matrix.py --seeds 20 --duration 120` (paired seeds),
# without → with: outdoors (octagonal trunks 0.4-0.8 m wide; judged noise 15-19 mm) laser
# yaw −0.077 → −0.020° (RMS 0.108 → 0.069°), RMS err/σ laser x 1.51 → 1.21 and yaw 1.68
# → 1.02; the radii and base not (+0.148 / +0.117 / +0.207 → +0.164 / +0.139 / +0.230 %,
# ± 0.04 / 0.04 / 0.08); indoor rows within their standard errors. Over 40 seeds (--rows 8)
# the yaw −0.075 → −0.041°. Not on a quieter laser: the real Mines URG-04LX (3 mm) has
# half its returns on pieces under 1 m (rough rock, pillars), and leaving their lines out
# moved its wheel base by up to 2 % (bench/measured_data.py, ad hoc). Tried ad hoc on the
# outdoor drives instead: the straightness judged without the return itself (from its six
# nearest others or its beam-order neighbours): laser y RMS 13-15 mm, radii RMS 0.5-1 %.
SMALL_OBJECT = 1.0  # m
SMALL_OBJECT_NOISE = 0.005  # m
# OFF_SEGMENTS: on a noisy laser the returns on no straight segment (pieces too short or too
# curved to give one: a parked car's end, the corner between its sides) get the line over
# their NORMAL_NEIGHBOURS beams and are measured from themselves, as on a quieter laser, and
# are paired along that line (ALONG_LINE); a segment's anchors keep the circle. Left
# without lines, outdoors few matches are confirmed (seed 1 at 2 cm: 59 of 395) and the
# wheels keep their nominal values. `python bench/sensor_matrix.py --factors outdoor --rows
# 3 4 --seeds 20 --duration 120`, with them: at 2 cm noise 20 of 20 seeds calibrated, radii
# and base −0.14 / −0.19 / −0.37 % (± 0.12 / 0.14 / 0.24), RMS err/σ 1.40 / 1.43 / 1.25
# (paired within a circle instead: 1.67 / 1.70 / 1.43); with a 60 m range +0.07 / +0.05 /
# +0.06 % (± 0.07 / 0.06 / 0.11), RMS err/σ 1.35 / 1.24 / 1.24; the laser yaw's σ is half
# its error in both (RMS err/σ 2.1). Indoors (`--rows 2 3 4 10 11 --seeds 80`, paired
# seeds) the corridors' URG-04LX-like radii and base +0.034 / +0.048 / +0.043 → +0.009 /
# +0.021 / +0.012 %, the office's low-cost +0.067 / +0.039 / +0.015 → +0.075 / +0.048 /
# +0.020 %, the other rows within 0.005 %. With the segments split as wall_segments now
# splits them, the same outdoor rows' RMS err/σ are 1.55 / 1.53 / 1.31 at 2 cm and 1.17 /
# 1.08 / 1.12 at 60 m, the laser yaw's 1.84 and 2.35 (docs/accuracy.md).


@dataclass
class ReferenceScan:
    """The points of a scan (laser frame) with a line normal at each, ready for pairing."""

    points: np.ndarray  # (N, 2), in the KD-tree: what a new point is paired with (anchors
    # on a noisy laser, so that no return is chosen for pairing by its own noise)
    normals: np.ndarray  # (N, 2)
    tree: cKDTree
    anchors: np.ndarray  # (N, 2) a point of each one's wall line, the residual's origin
    # Pairs whose anchor is farther than this from either scan's origin are not used
    # (CLEAR_OF_LIMIT); inf: the laser's range limit is unknown or far.
    usable_range: float = np.inf
    # (N,) m: how far along its line a new point may lie from each point and still be
    # paired with it (ALONG_LINE); None: within MAX_PAIR_DISTANCE of it.
    reach: np.ndarray | None = None
    # 1/m: the range noise grows as 1 + growth·r, and the new scan's points weigh
    # 1/(1 + growth·r)² (GROWTH); 0: alike. own_ranges (N,) m: the r of a point paired with
    # a return that is its own residual origin (its beam neighbours' median range); NaN for
    # a segment's anchor, where r is where the new point's beam meets the line.
    growth: float = 0.0
    own_ranges: np.ndarray | None = None

    @classmethod
    def from_points(cls, points, noise=None, usable_range=np.inf, small_objects=False,
                    beam_spacing=None, growth=0.0):
        """The scan's points on lines, with their normals, or None if fewer than 10 are.
        noise: None fits each line over NORMAL_NEIGHBOURS beams and measures residuals from
        the points themselves; a noisy laser's measured range noise (m) fits lines to whole
        straight segments and pairs with and measures from where the beams meet them
        (wall_segments.wall_lines; the returns on none as noise None: OFF_SEGMENTS).
        usable_range (m): lines farther than it are left out (see CLEAR_OF_LIMIT).
        small_objects: with noise None, returns on objects narrower than SMALL_OBJECT get
        no line (the laser's noise is enough to choose which of their lines pass).
        `points` are in beam order (scan_to_points): which way each return is used is
        judged from its neighbours in that order (BY_NEIGHBOURS).
        beam_spacing (rad): pair along the lines (ALONG_LINE) with the points that are
        their own residual origins.
        growth (1/m): how the range noise grows with range (GROWTH), for the segments' fit
        and the refinement's weights."""
        points = np.asarray(points, float)[:, :2]
        if len(points) < NORMAL_NEIGHBOURS + 1:
            return None
        normals, anchors, keep = line_decisions(points, noise, usable_range, small_objects,
                                                growth)
        # wall_lines leaves the returns on no segment their own anchors (OFF_SEGMENTS).
        own_origins = np.all(anchors == points, axis=1)
        reference = cls.of_kept(anchors, normals, anchors, keep, usable_range, beam_spacing,
                                own_origins)
        if reference is not None and growth:
            # A return that is its own origin is weighed by its neighbours' median range,
            # never its own: weighed by that, the returns its noise brought nearer would
            # weigh more (and the line through it moves with its noise).
            own_ranges = np.full(len(points), np.nan)
            returns = np.flatnonzero(own_origins & keep)
            own_ranges[returns] = neighbours_range(points, returns)
            reference.growth, reference.own_ranges = growth, own_ranges[keep]
        return reference

    @classmethod
    def of_kept(cls, points, normals, anchors, keep, usable_range=np.inf, beam_spacing=None,
                own_origins=None):
        """The ReferenceScan of the points where `keep` (line_decisions' answer), or None
        if fewer than 10 are; beam_spacing (rad): pair along the lines (ALONG_LINE) with the
        points that are their own residual origins (own_origins (N,) bool; None: all are),
        within MAX_PAIR_DISTANCE of the others (a segment's anchors)."""
        if keep.sum() < 10:
            return None
        kept_points = points[keep]
        reach = None
        if beam_spacing is not None:
            reach = _along_reach(kept_points, normals[keep], beam_spacing)
            if own_origins is not None:
                reach = np.where(own_origins[keep], reach, MAX_PAIR_DISTANCE)
        return cls(kept_points, normals[keep], cKDTree(kept_points), anchors[keep], usable_range,
                   reach)


def line_decisions(points, noise=None, usable_range=np.inf, small_objects=False, growth=0.0):
    """(normals (N, 2), residual origins (N, 2), keep (N,) bool) of each of the scan's points
    (N ≥ NORMAL_NEIGHBOURS + 1, beam order), as ReferenceScan.from_points describes."""
    if noise is None:
        normals, keep = _beam_lines(points, usable_range, small_objects)
        return normals, points, keep
    normals, anchors, keep = wall_lines(points, noise, usable_range, growth)
    # OFF_SEGMENTS: returns on no straight segment are measured from their own beams' lines.
    off_segments = np.flatnonzero(~normals.any(axis=1))
    if len(off_segments):
        normals[off_segments], keep[off_segments] = _beam_lines(points, usable_range,
                                                                small_objects, off_segments)
    return normals, anchors, keep


def _beam_lines(points, usable_range, small_objects, which=None):
    """(normals (M, 2), keep (M,) bool) of the returns points[which] (all if None): each
    one's line fitted over its NORMAL_NEIGHBOURS nearest returns, kept where it is straight,
    clear of the range limit and (with small_objects) not on an object narrower than
    SMALL_OBJECT."""
    which = np.arange(len(points)) if which is None else which
    _, idx = cKDTree(points).query(points[which], min(NORMAL_NEIGHBOURS, len(points)))
    normals, across, along = _line_fit(points, idx)
    straight = across < MAX_LINE_SPREAD
    if small_objects:
        straight &= _object_extent(points)[which] >= SMALL_OBJECT
    return normals, straight & (along > 0) & _neighbours_within(points, usable_range, which)


def _along_reach(points, normals, beam_spacing):
    """(N,) m: ALONG_LINE's reach along each point's line, from the beams' spacing on the
    surface there (range × spacing / cos of the incidence)."""
    distance = np.hypot(points[:, 0], points[:, 1])
    cos_incidence = np.abs(np.sum(normals * points, axis=1)) / np.maximum(distance, 1e-9)
    spacing = distance * beam_spacing / np.maximum(cos_incidence, MIN_COS_INCIDENCE)
    return np.clip(ALONG_REACH * spacing, MAX_PAIR_DISTANCE, ALONG_CAP)


def _beam_neighbours(points, which):
    """(idx (M, 6), exists (M, 6)): the three returns before and after each of the returns
    `which` (indices) in beam order, the return itself left out; `exists` is False past
    either end."""
    n = len(points)
    idx = which[:, None] + np.array([-3, -2, -1, 1, 2, 3])
    exists = (idx >= 0) & (idx < n)
    return np.clip(idx, 0, n - 1), exists


def _object_extent(points):
    """(N,) m: the extent of the object each return lies on: the diagonal of the box
    around its piece of the scan (wall_segments.scan_pieces)."""
    # A low-noise laser's breakpoint margin: 3σ of NOISY_RANGE.
    pieces, closed = scan_pieces(points, 3.0 * NOISY_RANGE)
    if closed:
        return np.full(len(points), np.inf)  # one closed surface around the laser
    extent = np.empty(len(points))
    for piece in pieces:
        size = points[piece].max(axis=0) - points[piece].min(axis=0)
        extent[piece] = math.hypot(size[0], size[1])
    return extent


def neighbours_range(points, which):
    """(M,) m: the median range of the neighbours in beam order of each of the returns
    `which` (indices), the return itself left out (BY_NEIGHBOURS)."""
    idx, exists = _beam_neighbours(points, which)
    return np.nanmedian(np.where(exists, np.hypot(points[idx, 0], points[idx, 1]), np.nan), axis=1)


def _neighbours_within(points, usable_range, which):
    """(M,) bool: the neighbours_range of each of the returns `which` (indices) is within
    `usable_range` (BY_NEIGHBOURS; all True when it is infinite)."""
    if not np.isfinite(usable_range):
        return np.ones(len(which), bool)
    return neighbours_range(points, which) <= usable_range


def _line_fit(points, idx):
    """(normals (N, 2), RMS spread across (N,), RMS spread along (N,)) of the line fitted to
    each point's neighbours points[idx] (N, k)."""
    nbr = points[idx]  # (N, k, 2)
    dx, dy = np.moveaxis(nbr - nbr.mean(axis=1, keepdims=True), -1, 0)  # (N, k) each
    count = idx.shape[1]
    # The 2×2 covariance of each neighbourhood and its eigen-decomposition in closed form
    # (np.linalg.eigh on N small matrices was a quarter of this function's time).
    cxx, cyy, cxy = (np.sum(dx * dx, 1) / count, np.sum(dy * dy, 1) / count,
                     np.sum(dx * dy, 1) / count)
    half_sum, radius = 0.5 * (cxx + cyy), np.hypot(0.5 * (cxx - cyy), cxy)
    direction = 0.5 * np.arctan2(2.0 * cxy, cxx - cyy)  # of the largest spread
    normals = np.column_stack([-np.sin(direction), np.cos(direction)])  # across the line
    return (normals, np.sqrt(np.maximum(half_sum - radius, 0.0)),
            np.sqrt(np.maximum(half_sum + radius, 0.0)))

