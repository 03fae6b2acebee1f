"""The reference scan of a match: its returns on lines, each with the line's normal and the
point residuals are measured from (its anchor), ready for pairing with a new scan's points.

How each return gets its line depends on the laser's judged noise (laser_noise.py); the
tuning is ReferenceLinesConfig and PairingConfig (config.py). Each choice below, and the
measurements behind it, in docs/decisions/point_to_line.md under the heading in quotes.

- A quiet laser's line at each return is fitted over its nearest few returns and kept
  where it is straight; residuals are measured from the return itself.
- A noisy laser's lines are its walls' whole straight segments, fitted on the returns'
  ranges, each return's anchor where its beam meets its segment's line (wall_segments.py).
  A few beams of a 3 cm laser span a few cm of wall: their line is off by tens of degrees,
  which lets the along-wall offsets of nearest-sample pairing (the point-to-point bias the
  refinement removes) back into the motion; paired with the nearest noisy return and
  measured from it, a residual shrinks wherever the new scan already is, and the match
  stays near its start. ("A noisy laser's lines: whole wall segments, fitted on ranges")
- On a noisy laser the returns on no straight segment (pieces too short or too curved to
  give one: a parked car's end, the corner between its sides) get the few beams' line and
  are measured from themselves, as on a quiet laser: left without lines, outdoors few
  matches are confirmed and the wheels keep their nominal values. ("Returns off the
  segments")
- Whether a return is used is decided from its neighbours in beam order, the return itself
  left out, never from where its own noise put it: decisions taken from its own position
  choose it for its noise, and the origins the refinement measures from then sit off the
  walls. (A noisy laser's anchors depend on a return's noise only through the fit of its
  whole segment.) ("Where the reference walls sit")
- A driver reports nothing where the measured range exceeds range_max, so of a wall near
  the limit only the returns whose noise brought them nearer are kept: the reference scan,
  the earlier of a pair, places a wall ahead too near, and the motion toward it comes out
  short. Leaving out returns by their measured range is the same cut again; lines whose
  anchor (or a quiet laser's return's neighbours) lie within clear_of_limit times the
  judged noise of the limit are left out instead, from either scan. ("The driver's cut at
  the range limit")
- On a laser whose lines are fitted over a few beams and whose judged noise is
  small_object_noise or more, a return on an object narrower than small_object (a tree
  trunk, a pole) gets no line: a few beams there span the object's corners, and whether
  their spread passes max_line_spread is decided by the returns' own noise, so the lines
  kept are chosen for their noise and the matches built on them come out turned. A
  quieter laser keeps them: on rough rock and pillars they are half its lines. Objects are
  the pieces of the scan between breakpoints. ("Returns on small objects")
- Where the beams are sparse on a surface, a new point is paired with a return that is its
  own origin when it lies in an ellipse around it, longer along the return's line by the
  beams' spacing there: within a circle, whether a point between two returns reaches one
  depends on that return's own noise, and outdoors (parked cars' sides, beams 30 cm and
  more apart on them) the matches come out long. A segment's anchors lie on whole
  segments' lines and keep the circle. ("Pairing along the line")
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from sclam_ros.frontend.config import FrontendConfig, PairingConfig
from sclam_ros.frontend.wall_segments import piece_bounds, wall_lines


@dataclass
class ReferenceScan:
    """The points of a scan (laser frame) with a line normal at each, ready for pairing."""

    points: np.ndarray  # (N, 2), in the KD-tree: what a new point is paired with (anchors
    # on a noisy laser, so that no return is chosen for pairing by its own noise)
    normals: np.ndarray  # (N, 2)
    tree: cKDTree
    anchors: np.ndarray  # (N, 2) a point of each one's wall line, the residual's origin
    # Pairs whose anchor is farther than this from either scan's origin are not used (clear
    # of the range limit); inf: the laser's range limit is unknown or far.
    usable_range: float = np.inf
    # (N,) m: how far along its line a new point may lie from each point and still be
    # paired with it; None: within PairingConfig.max_pair_distance of it.
    reach: np.ndarray | None = None
    # 1/m: the range noise grows as 1 + growth·r, and the new scan's points weigh
    # 1/(1 + growth·r)² (laser_noise.py); 0: alike. own_ranges (N,) m: the r of a point
    # paired with a return that is its own residual origin (its beam neighbours' median
    # range); NaN for a segment's anchor, where r is where the new point's beam meets the line.
    growth: float = 0.0
    own_ranges: np.ndarray | None = None

    @classmethod
    def from_points(cls, points, noise=None, usable_range=np.inf, small_objects=False,
                    beam_spacing=None, growth=0.0, config: FrontendConfig = FrontendConfig()):
        """The scan's points on lines, with their normals, or None if fewer than 10 are.
        noise: None fits each line over config.reference_lines.normal_neighbours beams and
        measures residuals from the points themselves; a noisy laser's measured range noise
        (m) fits lines to whole straight segments and pairs with and measures from where the
        beams meet them (wall_segments.wall_lines; the returns on none as noise None).
        usable_range (m): lines farther than it are left out (clear of the range limit).
        small_objects: with noise None, returns on objects narrower than
        config.reference_lines.small_object get no line (the laser's noise is enough to
        choose which of their lines pass).
        `points` are in beam order (scan_to_points): which way each return is used is
        judged from its neighbours in that order.
        beam_spacing (rad): pair along the lines with the points that are their own
        residual origins.
        growth (1/m): how the range noise grows with range (laser_noise.py), for the
        segments' fit and the refinement's weights."""
        points = np.asarray(points, float)[:, :2]
        if len(points) < config.reference_lines.normal_neighbours + 1:
            return None
        normals, anchors, keep = line_decisions(points, noise, usable_range, small_objects,
                                                growth, config)
        # wall_lines leaves the returns on no segment their own anchors.
        own_origins = np.all(anchors == points, axis=1)
        reference = cls.of_kept(anchors, normals, anchors, keep, usable_range, beam_spacing,
                                own_origins, config.pairing)
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
                own_origins=None, config: PairingConfig = PairingConfig()):
        """The ReferenceScan of the points where `keep` (line_decisions' answer), or None
        if fewer than 10 are; beam_spacing (rad): pair along the lines with the points that
        are their own residual origins (own_origins (N,) bool; None: all are), within
        config.max_pair_distance of the others (a segment's anchors)."""
        if keep.sum() < 10:
            return None
        kept_points = points[keep]
        reach = None
        if beam_spacing is not None:
            reach = _along_reach(kept_points, normals[keep], beam_spacing, config)
            if own_origins is not None:
                reach = np.where(own_origins[keep], reach, config.max_pair_distance)
        return cls(kept_points, normals[keep], cKDTree(kept_points), anchors[keep], usable_range,
                   reach)


def line_decisions(points, noise=None, usable_range=np.inf, small_objects=False, growth=0.0,
                   config: FrontendConfig = FrontendConfig()):
    """(normals (N, 2), residual origins (N, 2), keep (N,) bool) of each of the scan's points
    (N > config.reference_lines.normal_neighbours, beam order), as
    ReferenceScan.from_points describes."""
    if noise is None:
        normals, keep = _beam_lines(points, usable_range, small_objects, None, config)
        return normals, points, keep
    normals, anchors, keep = wall_lines(points, noise, usable_range, growth,
                                        config.wall_segments)
    # Returns on no straight segment are measured from their own beams' lines.
    off_segments = np.flatnonzero(~normals.any(axis=1))
    if len(off_segments):
        normals[off_segments], keep[off_segments] = _beam_lines(
            points, usable_range, small_objects, off_segments, config)
    return normals, anchors, keep


def _beam_lines(points, usable_range, small_objects, which, config: FrontendConfig):
    """(normals (M, 2), keep (M,) bool) of the returns points[which] (all if None): each
    one's line fitted over its config.reference_lines.normal_neighbours nearest returns,
    kept where it is straight, clear of the range limit and (with small_objects) not on an
    object narrower than config.reference_lines.small_object."""
    lines = config.reference_lines
    which = np.arange(len(points)) if which is None else which
    _, idx = cKDTree(points).query(points[which], min(lines.normal_neighbours, len(points)))
    normals, across, along = _line_fit(points, idx)
    straight = across < lines.max_line_spread
    if small_objects:
        straight &= _object_extent(points, config)[which] >= lines.small_object
    return normals, straight & (along > 0) & _neighbours_within(points, usable_range, which)


def _along_reach(points, normals, beam_spacing, config: PairingConfig):
    """(N,) m: how far along each point's line a new point may lie and be paired with it:
    config.along_reach times the beams' spacing on the surface there (range × spacing / cos
    of the incidence), within config.max_pair_distance … config.along_cap."""
    distance = np.hypot(points[:, 0], points[:, 1])
    cos_incidence = np.abs(np.sum(normals * points, axis=1)) / np.maximum(distance, 1e-9)
    spacing = distance * beam_spacing / np.maximum(cos_incidence, config.min_cos_incidence)
    return np.clip(config.along_reach * spacing, config.max_pair_distance, config.along_cap)


def _beam_neighbours(points, which):
    """(idx (M, 6), exists (M, 6)): the three returns before and after each of the returns
    `which` (indices) in beam order, the return itself left out; `exists` is False past
    either end."""
    n = len(points)
    idx = which[:, None] + np.array([-3, -2, -1, 1, 2, 3])
    exists = (idx >= 0) & (idx < n)
    return np.clip(idx, 0, n - 1), exists


def _object_extent(points, config: FrontendConfig):
    """(N,) m: the extent of the object each return lies on: the diagonal of the box
    around its piece of the scan (wall_segments.scan_pieces)."""
    # A low-noise laser's breakpoint margin: 3σ of the noise from which a laser is noisy.
    order, starts, closed = piece_bounds(points, 3.0 * config.laser_noise.noisy_range,
                                         config.wall_segments)
    if closed:
        return np.full(len(points), np.inf)  # one closed surface around the laser
    # The pieces are runs of `order`: their boxes in one pass over the scan.
    ordered = points[order]
    size = np.maximum.reduceat(ordered, starts) - np.minimum.reduceat(ordered, starts)
    lengths = np.diff(np.append(starts, len(order)))
    extent = np.empty(len(points))
    extent[order] = np.repeat([math.hypot(dx, dy) for dx, dy in size.tolist()], lengths)
    return extent


def neighbours_range(points, which):
    """(M,) m: the median range of the neighbours in beam order of each of the returns
    `which` (indices), the return itself left out: nothing about it depends on the
    return's own noise."""
    idx, exists = _beam_neighbours(points, which)
    ranges = np.where(exists, np.hypot(points[:, 0], points[:, 1])[idx], np.nan)
    return _nan_median_rows(ranges)


def _nan_median_rows(values):
    """np.nanmedian(values, axis=1) of an (M, k) array whose rows each hold at least one
    number: sorted, the NaNs go last, and each row's median is the mean of its middle pair
    among the numbers (run once per reference scan; np.nanmedian goes through masked
    arrays, several times slower on small rows)."""
    ordered = np.sort(values, axis=1)
    count = np.count_nonzero(~np.isnan(values), axis=1)
    rows = np.arange(len(values))
    return (ordered[rows, (count - 1) // 2] + ordered[rows, count // 2]) / 2.0


def _neighbours_within(points, usable_range, which):
    """(M,) bool: the neighbours_range of each of the returns `which` (indices) is within
    `usable_range` (all True when it is infinite). Judged by the return's own range it
    would be the driver's cut at the range limit again."""
    if not np.isfinite(usable_range):
        return np.ones(len(which), bool)
    return neighbours_range(points, which) <= usable_range


def _line_fit(points, idx):
    """(normals (N, 2), RMS spread across (N,), RMS spread along (N,)) of the line fitted to
    each point's neighbours points[idx] (N, k)."""
    nbr = points[idx]  # (N, k, 2)
    dx, dy = np.moveaxis(nbr - nbr.mean(axis=1, keepdims=True), -1, 0)  # (N, k) each
    count = idx.shape[1]
    # The 2×2 covariance of each neighbourhood and its eigen-decomposition in closed form,
    # faster than np.linalg.eigh on N small matrices.
    cxx, cyy, cxy = (np.sum(dx * dx, 1) / count, np.sum(dy * dy, 1) / count,
                     np.sum(dx * dy, 1) / count)
    half_sum, radius = 0.5 * (cxx + cyy), np.hypot(0.5 * (cxx - cyy), cxy)
    direction = 0.5 * np.arctan2(2.0 * cxy, cxx - cyy)  # of the largest spread
    normals = np.column_stack([-np.sin(direction), np.cos(direction)])  # across the line
    return (normals, np.sqrt(np.maximum(half_sum - radius, 0.0)),
            np.sqrt(np.maximum(half_sum + radius, 0.0)))

