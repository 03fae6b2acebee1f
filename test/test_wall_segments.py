import math

import numpy as np

from sclam_ros.frontend import wall_segments
from sclam_ros.frontend.config import WallSegmentsConfig
from sclam_ros.sim.world import World, _polyline


def _wall_returns(bearings, normal_angle, distance, noise, rng):
    """Returns of the wall n·x = distance (n at normal_angle) on beams at `bearings`, with
    Gaussian range noise."""
    ranges = distance / np.cos(bearings - normal_angle) + rng.normal(0.0, noise, bearings.shape)
    return np.column_stack([ranges * np.cos(bearings), ranges * np.sin(bearings)])


def test_a_line_fitted_on_ranges_does_not_lean_toward_the_beams():
    """A wall seen obliquely (incidence 35-65°), 5 cm of range noise: each return's noise
    moves it along its beam, across and along the wall at once, so a least-squares line
    through the points turns toward the beams (by about σ²·sin i·cos i over the variance
    of the points along the wall: 0.09° here). Fitted on the ranges it does not."""
    rng = np.random.default_rng(4)
    bearings = np.radians(np.arange(35.0, 65.0, 0.5))
    true_angle, true_distance = 0.0, 2.0
    through_points, on_ranges = [], []
    for _ in range(2000):
        p = _wall_returns(bearings, true_angle, true_distance, 0.05, rng)
        normal, centre, _, _ = wall_segments._total_least_squares(p)
        normal = normal if normal[0] > 0 else -normal
        through_points.append(math.atan2(normal[1], normal[0]))
        fitted, _ = wall_segments._fit_on_ranges(p, normal, centre, 0.0, WallSegmentsConfig())
        on_ranges.append(math.atan2(fitted[1], fitted[0]))
    through_points, on_ranges = np.degrees(through_points), np.degrees(on_ranges)
    standard_error = on_ranges.std() / math.sqrt(len(on_ranges))
    assert abs(through_points.mean()) > 0.05 > 5 * standard_error
    assert abs(on_ranges.mean()) < 3 * standard_error


def test_a_line_fitted_on_ranges_weighs_its_far_returns_less_where_their_noise_grows():
    """A wall 1 m away seen 1 to 8 m along it, range noise 2 cm + 1 % of range: the
    fit weighted by 1/σ(r)² (growth 0.5/m) is the maximum-likelihood one, unbiased and
    with smaller errors than the fit that weighs every return alike (Gauss-Markov)."""
    rng = np.random.default_rng(6)
    bearings = np.arctan2(1.0, np.linspace(1.0, 8.0, 200))  # on the wall y = 1 (normal at 90°)
    true_distance = 1.0
    errors = {0.0: [], 0.5: []}
    for _ in range(1000):
        true_ranges = true_distance / np.sin(bearings)
        ranges = true_ranges + rng.normal(0.0, 1.0, bearings.shape) * (0.02 + 0.01 * true_ranges)
        p = np.column_stack([ranges * np.cos(bearings), ranges * np.sin(bearings)])
        normal, centre, _, _ = wall_segments._total_least_squares(p)
        for growth, found in errors.items():
            fitted, distance = wall_segments._fit_on_ranges(p, normal, centre, growth,
                                                            WallSegmentsConfig())
            found.append((math.degrees(math.atan2(fitted[1], fitted[0])) - 90.0,
                          distance - true_distance))
    alike, weighted = np.array(errors[0.0]), np.array(errors[0.5])
    rms_alike, rms_weighted = np.sqrt(np.mean(alike ** 2, 0)), np.sqrt(np.mean(weighted ** 2, 0))
    assert np.all(rms_weighted < 0.92 * rms_alike)  # 0.87 and 0.86 on these draws
    assert np.all(np.abs(weighted.mean(0)) < 3 * weighted.std(0) / math.sqrt(len(weighted)))


def test_scan_pieces_cut_at_range_jumps_and_join_across_the_seam():
    """A full turn of a round room with a pillar in front: the pillar is a piece of its own;
    the wall behind is one piece on each side of it, and the wall's last and first returns
    (across the scan's seam) belong to one piece."""
    bearings = np.radians(np.arange(-180.0, 180.0, 1.0))
    ranges = np.full(bearings.shape, 4.0)
    pillar = np.abs(bearings) < np.radians(5.0)
    ranges[pillar] = 1.0
    points = np.column_stack([ranges * np.cos(bearings), ranges * np.sin(bearings)])
    pieces, closed = wall_segments.scan_pieces(points, 0.06)
    assert not closed
    assert sorted(len(p) for p in pieces) == [pillar.sum(), len(bearings) - pillar.sum()]
    wall = next(p for p in pieces if len(p) > pillar.sum())
    assert {0, len(bearings) - 1} <= set(wall.tolist())  # across the seam
    round_room = 4.0 * np.column_stack([np.cos(bearings), np.sin(bearings)])
    one_surface, closed = wall_segments.scan_pieces(round_room, 0.06)
    assert closed and len(one_surface) == 1


def test_straight_segments_split_a_room_at_its_corners_only():
    """A laser inside a 6 m × 4 m room, 2 cm range noise: four segments, one per wall, each
    holding only returns of its own wall, and together nearly all returns."""
    rng = np.random.default_rng(2)
    bearings = np.radians(np.arange(-180.0, 180.0, 0.5))
    c, s = np.cos(bearings), np.sin(bearings)
    with np.errstate(divide="ignore"):
        to_x = np.where(c > 0, 2.0 / c, np.where(c < 0, -4.0 / c, np.inf))  # walls x = 2, x = -4
        to_y = np.where(s > 0, 1.5 / s, np.where(s < 0, -2.5 / s, np.inf))  # walls y = 1.5, -2.5
    on_x = to_x < to_y
    ranges = np.minimum(to_x, to_y) + rng.normal(0.0, 0.02, bearings.shape)
    points = np.column_stack([ranges * c, ranges * s])
    wall = np.where(on_x, np.sign(c), 2 * np.sign(s))  # ±1: x walls, ±2: y walls
    segments = wall_segments.straight_segments(points, 0.02)
    assert len(segments) == 4
    assert sum(len(segment) for segment in segments) > 0.95 * len(points)
    for segment in segments:
        # All of one wall but the few returns at its corners the split may give the other.
        assert np.mean(wall[segment] == np.median(wall[segment])) > 0.97
        assert len(segment) > 60


def _polygon_room_returns(corner_bearings, radius, bearings, noise, rng):
    """Returns on beams at `bearings` inside a convex room whose corners lie on a circle of
    `radius` around the laser at `corner_bearings` (rad, increasing)."""
    corners = [(radius * math.cos(a), radius * math.sin(a)) for a in corner_bearings]
    room = World(np.array(_polyline(*corners, corners[0]), float))
    ranges = room.raycast((0.0, 0.0, 0.0), bearings, 2.0 * radius)
    ranges = ranges + rng.normal(0.0, noise, bearings.shape)
    return np.column_stack([ranges * np.cos(bearings), ranges * np.sin(bearings)])


def test_a_wall_too_short_for_a_segment_at_a_closed_scans_seam_is_left_out():
    """A closed scan whose first and last returns lie on a wall too short to be a segment
    (4° wide across the seam): no segment holds the first return, nothing is joined across
    the seam, and the long walls are one segment each."""
    rng = np.random.default_rng(9)  # a draw that leaves the scan's first returns out
    bearings = np.radians(np.arange(-180.0, 180.0, 0.5))
    corner_bearings = np.radians([-178.0, -90.0, 0.0, 90.0, 178.0])
    points = _polygon_room_returns(corner_bearings, 3.0, bearings, 0.02, rng)
    assert wall_segments.scan_pieces(points, 0.08)[1]  # closed: no breakpoint
    segments = wall_segments.straight_segments(points, 0.02)
    assert len(segments) == 4 and not any(0 in segment for segment in segments)
    on_short_wall = np.abs(bearings) > np.radians(178.0)
    for segment in segments:
        # At most the returns near a corner that the split may give the other wall (the
        # short wall turns by 4° only).
        assert on_short_wall[segment].sum() <= 4
        assert len(segment) > 150
