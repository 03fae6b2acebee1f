"""The reference scan's lines (frontend/reference_lines.py): which returns get a line, its
normal and the point residuals are measured from."""
import numpy as np

from sclam_ros.frontend import reference_lines, wall_segments
from sclam_ros.frontend.config import FrontendConfig

from test_point_to_line import ANGLES, _box_room_points

CONFIG = FrontendConfig()


def _normal_errors(reference, true_normal):
    """Angle (rad) between each kept point's normal and the true one (sign-free)."""
    cos = np.abs(reference.normals @ np.asarray(true_normal, float))
    return np.arccos(np.clip(cos, -1.0, 1.0))


def test_segment_lines_follow_a_noisy_wall():
    """A URG-04LX-like wall (1 cm between beams, 3 cm range noise): six beams span 5 cm, so
    their line is off by tens of degrees; fitted over 30 beams (0.3 m) it is within a few.
    The expected error of a line fitted to n points over a length L with noise σ is about
    σ·sqrt(12 / n) / L: 0.03·sqrt(12/6)/0.05 ≈ 0.8 rad for six, ≈ 0.06 rad for 30."""
    rng = np.random.default_rng(7)
    y = np.arange(-1.5, 1.5, 0.01)
    wall = np.column_stack([2.0 + rng.normal(0.0, 0.03, y.size), y])
    narrow = reference_lines.ReferenceScan.from_points(wall)
    wide = reference_lines.ReferenceScan.from_points(wall, noise=0.03)
    # Six beams pass the straightness test on most of the wall (their spread across it is
    # below 2 cm) with wrong normals; 30 beams over 0.3 m pass where the noise allows.
    assert len(narrow.points) > 0.8 * len(wall)
    assert np.sqrt(np.mean(_normal_errors(narrow, (1.0, 0.0)) ** 2)) > 0.3
    assert len(wide.points) > 0.4 * len(wall)
    assert np.sqrt(np.mean(_normal_errors(wide, (1.0, 0.0)) ** 2)) < 0.1


def test_segment_lines_keep_corners_out():
    """Two walls meeting at a right angle, 3 cm range noise: the scan is split at the corner,
    every return used gets its own wall's line, its anchor (where its beam meets that line)
    on that wall, and the returns near the corner, which the noise could have put on either
    wall, are not used. One line through the corner would lean by tens of degrees and move
    the anchors near it by centimetres."""
    rng = np.random.default_rng(11)
    bearings = np.radians(np.arange(-30.0, 120.0, 0.36))
    # Walls x = 2 m and y = 3 m; each beam's true range is to the nearer of the two.
    to_x_wall, to_y_wall = 2.0 / np.cos(bearings), 3.0 / np.sin(bearings)
    on_x_wall = (np.cos(bearings) > 0) & ((to_x_wall < to_y_wall) | (np.sin(bearings) <= 0))
    true = np.where(on_x_wall, to_x_wall, to_y_wall)
    wall_normal = np.where(on_x_wall[:, None], [1.0, 0.0], [0.0, 1.0])
    near_corner = np.hypot(true * np.cos(bearings) - 2.0, true * np.sin(bearings) - 3.0) < 0.03
    for _ in range(20):
        ranges = true + rng.normal(0.0, 0.03, true.shape)
        points = np.column_stack([ranges * np.cos(bearings), ranges * np.sin(bearings)])
        normals, anchors, keep = reference_lines.line_decisions(points, noise=0.03)
        assert keep.sum() > 0.95 * len(points) and not keep[near_corner].any()
        assert np.all(np.abs(np.sum(normals * wall_normal, axis=1))[keep] > np.cos(0.05))
        off_wall = np.where(on_x_wall, anchors[:, 0] - 2.0, anchors[:, 1] - 3.0)[keep]
        assert np.max(np.abs(off_wall)) < 0.02


def test_line_anchors_stay_on_the_wall_near_corners():
    """The residual's origin on a noisy laser is where the return's beam meets its segment's
    line; near a corner, where a line fitted through both walls' returns would sit toward
    the laser, it stays within half a millimetre of the wall on average (3 cm range noise;
    about −0.2 mm)."""
    rng = np.random.default_rng(3)
    offsets = []
    for _ in range(200):  # the mean's standard error: about 0.3 mm
        reference = reference_lines.ReferenceScan.from_points(_box_room_points(np.zeros(3), 0.03, rng), noise=0.03)
        # the far wall (x = 2.5) between 0.1 and 0.5 m from its corners with the side walls
        near_corner = ((np.abs(reference.points[:, 0] - 2.5) < 0.15)
                       & (np.abs(np.abs(reference.points[:, 1]) - 1.7) < 0.2))
        offsets.append(reference.anchors[near_corner, 0] - 2.5)
    offsets = np.concatenate(offsets)
    assert len(offsets) > 4000
    assert abs(np.mean(offsets)) < 0.0005


def test_anchors_sit_on_their_walls_under_range_proportional_noise():
    """A noisy laser's residual origins (anchors, where each return's beam meets its
    segment's line) sit on the simulator's walls: on average within 0.2 mm at 2-4 m (two
    120 s routes of the office, a 720-beam laser with 2 cm + 1 % of range noise and 10 %
    dropouts; docs/decisions/point_to_line.md). A least-squares line through the returns leans
    toward the beams, and origins chosen by the returns' own noise sat +1.1 mm beyond."""
    from sclam_ros.core import se2
    from sclam_ros.sim.motion import TrueKinematics
    from sclam_ros.sim.trajectory import simulate_trajectory
    from sclam_ros.sim.world import office_world

    world = office_world()
    angles = np.linspace(-np.pi, np.pi, 720, endpoint=False)
    offsets = []
    for seed in (1, 3):
        route = simulate_trajectory(world, TrueKinematics(0.1265, 0.1275, 0.5825), 120.0, seed, 0.3, 50.0)
        rng = np.random.default_rng(seed)
        for pose in se2.compose(route.pose_at(np.arange(0.0, route.duration, 0.3)), np.array([0.2, 0.0, 0.0])):
            true = world.raycast(pose, angles, 12.0)
            seen = np.isfinite(true)
            ranges = true[seen] + rng.standard_normal(seen.sum()) * (0.02 + 0.01 * true[seen])
            returned = (ranges <= 12.0) & (rng.random(seen.sum()) >= 0.1)
            points = np.column_stack([ranges * np.cos(angles[seen]), ranges * np.sin(angles[seen])])[returned]
            reference = reference_lines.ReferenceScan.from_points(points, 0.056, 12.0 - 3 * 0.056)
            p, n = reference.anchors, reference.normals
            bearing = np.arctan2(p[:, 1], p[:, 0])
            wall = world.raycast(pose, bearing, 24.0)  # the return's own beam
            on_wall = np.column_stack([wall * np.cos(bearing), wall * np.sin(bearing)])
            beyond = np.sum((p - on_wall) * n, axis=1) * np.sign(np.sum(n * p, axis=1))
            offsets.append(beyond[(wall >= 2.0) & (wall < 4.0)])
    offsets = np.concatenate(offsets)
    assert len(offsets) > 10000
    assert abs(offsets.mean()) < 0.0002, offsets.mean()


def _room_with_trunk(angles, trunk=(3.0, 0.0), radius=0.3):
    """Ranges in a 10 m × 10 m room centred on the laser, with a round trunk standing in it."""
    d = np.column_stack([np.cos(angles), np.sin(angles)])
    with np.errstate(divide="ignore"):
        walls = np.min(np.where(np.abs(d) > 1e-9, 5.0 / np.abs(d), np.inf), axis=1)
    centre = np.asarray(trunk)
    along = d @ centre
    disc = along ** 2 - (centre @ centre - radius ** 2)
    hit = (disc > 0) & (along > 0)
    trunk_range = np.where(hit, along - np.sqrt(np.where(hit, disc, 0.0)), np.inf)
    return np.minimum(walls, trunk_range)


def test_object_extent_tells_a_trunk_from_the_walls_behind_it():
    ranges = _room_with_trunk(ANGLES)
    points = np.column_stack([ranges * np.cos(ANGLES), ranges * np.sin(ANGLES)])
    extent = reference_lines._object_extent(points, CONFIG)
    on_trunk = np.hypot(points[:, 0] - 3.0, points[:, 1]) < 0.31
    assert on_trunk.sum() >= 8
    # The trunk's visible half: at most its 0.6 m diameter.
    assert np.all(extent[on_trunk] <= 0.6 + 1e-6)
    # The walls are one piece around the laser (across the scan's seam), the room's diagonal.
    assert np.allclose(extent[~on_trunk], np.hypot(10.0, 10.0), atol=0.05)
    # Half a turn: its two ends are not consecutive returns, and its walls still one piece each side.
    half = (ANGLES > -np.pi / 2) & (ANGLES < np.pi / 2)
    assert np.all(reference_lines._object_extent(points[half], CONFIG)[~on_trunk[half]] > 4.0)


def test_small_objects_get_no_line_on_a_noisy_laser():
    rng = np.random.default_rng(7)
    ranges = _room_with_trunk(ANGLES, trunk=(1.5, 0.5), radius=0.4) + rng.normal(0.0, 0.01, len(ANGLES))
    points = np.column_stack([ranges * np.cos(ANGLES), ranges * np.sin(ANGLES)])
    near_trunk = lambda p: np.hypot(p[:, 0] - 1.5, p[:, 1] - 0.5) < 0.45  # noqa: E731
    plain = reference_lines.ReferenceScan.from_points(points)
    ruled = reference_lines.ReferenceScan.from_points(points, small_objects=True)
    assert near_trunk(plain.points).sum() > 0  # its faces pass the straightness test
    assert near_trunk(ruled.points).sum() == 0
    assert len(ruled.points) == len(plain.points) - near_trunk(plain.points).sum()


def test_a_noisy_laser_measures_from_beam_lines_where_no_segment_is_long_enough():
    """A surface with too few returns for a segment line (a car's side 8 m away: 9 beams)
    still gets lines on a noisy laser, each over its return's beam neighbours, measured from
    the return itself; the long wall's returns keep their segment's anchors."""
    rng = np.random.default_rng(5)
    bearing = np.radians(np.arange(-60.0, 121.0))
    wall = (bearing > np.radians(40.0)) & (bearing < np.radians(140.0))  # y = 3 m
    side = np.abs(np.tan(bearing) * 8.0) <= 0.6  # x = 8 m, 1.2 m long
    with np.errstate(divide="ignore"):
        ranges = np.where(wall, 3.0 / np.sin(bearing), 8.0 / np.cos(bearing))
    keep = wall | side
    ranges = ranges[keep] + rng.normal(0.0, 0.002, keep.sum())
    points = np.column_stack([ranges * np.cos(bearing[keep]), ranges * np.sin(bearing[keep])])
    on_side = points[:, 0] > 7.0
    assert 6 <= on_side.sum() < CONFIG.wall_segments.min_segment_returns

    segment_normals, _, segment_keep = wall_segments.wall_lines(points, 0.02)
    normals, anchors, kept = reference_lines.line_decisions(points, noise=0.02)
    assert not segment_keep[on_side].any()
    assert kept[on_side].sum() >= on_side.sum() - 2  # the ends' neighbourhoods take in the gap
    assert np.array_equal(anchors[on_side], points[on_side])
    assert np.all(np.abs(normals[on_side & kept, 0]) > np.cos(np.radians(5.0)))
    # The wall's returns are as the segment fit left them.
    assert np.array_equal(kept[~on_side], segment_keep[~on_side])
    assert np.array_equal(normals[~on_side], segment_normals[~on_side])
