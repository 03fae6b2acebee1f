import numpy as np
import pytest

from sclam_ros.frontend import point_to_line, reference_lines
from sclam_ros.frontend.config import FrontendConfig
from sclam_ros.core import se2
from sclam_ros.sim.world import office_world

CONFIG = FrontendConfig()

ANGLES = -np.pi + 2 * np.pi / 360 * np.arange(360)


def scan_points(world, pose, noise=0.0, rng=None):
    ranges = world.raycast(pose, ANGLES, 20.0)
    if noise:
        ranges = ranges + rng.normal(0, noise, ranges.shape)
    ok = np.isfinite(ranges)
    return np.column_stack([ranges[ok] * np.cos(ANGLES[ok]), ranges[ok] * np.sin(ANGLES[ok])])


@pytest.mark.parametrize("motion", [(0.04, 0.0, 0.0), (0.03, 0.01, 0.08), (0.0, 0.0, 0.1)])
def test_refine_recovers_exact_motion_from_a_perturbed_start(motion):
    world = office_world()
    start = np.array([6.0, 3.0, 0.3])
    end = se2.compose(start, np.array(motion))
    reference = reference_lines.ReferenceScan.from_points(scan_points(world, start))
    z0 = np.array(motion) + [0.02, -0.015, 0.01]  # a scan matcher's answer, cm off
    z, used = point_to_line.refine(reference, scan_points(world, end), z0)
    assert used > 100
    # Noise-free geometry: the remaining error is the chord-vs-wall discretisation only.
    assert np.allclose(z[:2], motion[:2], atol=1e-3)
    assert z[2] == pytest.approx(motion[2], abs=2e-4)


def test_refine_is_unbiased_along_walls_under_range_noise():
    """The point-to-point failure mode: forward motion along walls is under-estimated.
    Point-to-line must average to the true forward motion (bias below 1 % of the step)."""
    world = office_world()
    rng = np.random.default_rng(4)
    errors = []
    for i in range(60):
        start = np.array([4.0 + 0.1 * i, 2.5, 0.0])
        motion = np.array([0.04, 0.0, 0.0])
        reference = reference_lines.ReferenceScan.from_points(scan_points(world, start, 0.01, rng))
        z, _ = point_to_line.refine(reference, scan_points(world, se2.compose(start, motion), 0.01, rng),
                                    motion * 0.97)
        errors.append(z - motion)
    errors = np.array(errors)
    standard_error = errors[:, 0].std() / np.sqrt(len(errors))
    assert abs(errors[:, 0].mean()) < max(4e-4, 4 * standard_error)


def test_too_few_points_fall_back_to_the_initial_guess():
    pts = np.array([[1.0, 0.0], [1.0, 0.1], [1.0, 0.2]])
    assert reference_lines.ReferenceScan.from_points(pts) is None
    line = np.column_stack([np.full(40, 2.0), np.linspace(-1, 1, 40)])
    reference = reference_lines.ReferenceScan.from_points(line)
    z0 = np.array([0.01, 0.0, 0.0])
    z, used = point_to_line.refine(reference, line[:5], z0)
    assert used == 0 and np.allclose(z, z0)
    # A scan without lines has no reference at all: the initial guess stands.
    z, used = point_to_line.refine(None, line, z0)
    assert used == 0 and np.allclose(z, z0)


def test_outdoors_only_confirmed_matches_are_used():
    """Outdoors (tree trunks, poles, cars) the few "lines" a scan has join points of different
    objects, and KISS-ICP's answers are off by centimetres where nothing confirms them. The
    matches the refinement cannot confirm are not used (counted by reason); the ones used
    are closer to the truth than KISS-ICP's (median error 11 against 21 mm on this drive)."""
    from sclam_ros.frontend.scan_matching import ScanMatcher, scan_to_points
    from sclam_ros.sim.motion import TrueKinematics
    from sclam_ros.sim.sensors import LaserModel
    from sclam_ros.sim.trajectory import simulate_trajectory
    from sclam_ros.sim.world import outdoor_world

    world = outdoor_world()
    trajectory = simulate_trajectory(world, TrueKinematics(0.1, 0.1, 0.5), 40.0, 1, robot_radius=0.3)
    stamps = np.arange(0.0, trajectory.duration, 0.1)
    poses = trajectory.pose_at(stamps)
    model = LaserModel()
    rng = np.random.default_rng(0)
    scans = [model.measure(world.raycast(p, model.angles(), model.range_max), rng) for p in poses]
    from sclam_ros.core.inputs import Scan

    p99, med = {}, {}
    for refine in (False, True):
        matcher = ScanMatcher()
        refined_matcher = point_to_line.RefinedScanMatcher(matcher) if refine else None
        errors, used = [], 0
        not_used = 0
        for i, (t, ranges) in enumerate(zip(stamps, scans)):
            scan = Scan(float(t), ranges, model.angle_min, model.angle_increment, model.range_min, model.range_max)
            guess = se2.between(poses[i], poses[i - 1]) if i else None
            points = scan_to_points(scan)
            if refine:
                match, z, _ = refined_matcher.add_scan(scan, guess, points)
            else:
                match = matcher.add_scan(scan, guess, points)
                z = None if match is None else match.z
            if match is not None and z is None:
                not_used += 1
            if z is not None:
                truth = se2.between(poses[match.index_to], poses[match.index_from])
                errors.append(np.hypot(*(z[:2] - truth[:2])))
                used += 1
        p99[refine] = np.percentile(errors, 99)
        med[refine] = np.median(errors)
    assert not_used > 0 and sum(refined_matcher.unrefined.values()) == not_used
    assert refined_matcher.matches == not_used + used
    assert med[True] < 0.7 * med[False], med
    assert p99[True] <= 1.2 * p99[False], p99


def _walls(segments, spacing=0.02):
    return np.concatenate([np.linspace(a, b, int(np.hypot(*np.subtract(b, a)) / spacing))
                           for a, b in segments])


def test_refinement_covariance_is_large_where_the_walls_do_not_fix_the_motion():
    """Down a corridor (two walls along x) the lines fix y and the heading but not x: the
    refinement's covariance says so, and in a closed room it does not."""
    rng = np.random.default_rng(5)
    corridor = [((-3.0, -1.0), (3.0, -1.0)), ((-3.0, 1.0), (3.0, 1.0))]
    room = corridor + [((-3.0, -1.0), (-3.0, 1.0)), ((3.0, -1.0), (3.0, 1.0))]
    motion = np.array([0.05, 0.0, 0.0])
    for segments, closed in ((corridor, False), (room, True)):
        reference = reference_lines.ReferenceScan.from_points(_walls(segments))
        scan = se2.transform_points(se2.inverse(motion), _walls(segments))
        scan = scan + rng.normal(0.0, 0.005, scan.shape)
        z, used, covariance = point_to_line.refine_with_covariance(reference, scan, motion)
        assert used > 200 and np.all(np.linalg.eigvalsh(covariance) > 0)
        ratio = covariance[0, 0] / covariance[1, 1]
        assert (ratio < 10.0) if closed else (ratio > 100.0)


URG_ANGLES = np.radians(np.linspace(-120.0, 120.0, 683))  # a URG-04LX's beams


def _box_room_points(pose, noise, rng, half_x=2.5, half_y=2.0, angles=URG_ANGLES):
    """A URG-04LX-like laser (3 cm range noise; or beams at `angles`) at `pose` in a closed
    5 × 4 m room centred at the origin: its returns in the laser frame."""
    bearing = angles + pose[2]
    c, s = np.cos(bearing), np.sin(bearing)
    ranges = np.full(bearing.shape, np.inf)
    with np.errstate(divide="ignore"):
        for wall in (-half_x, half_x):
            t = (wall - pose[0]) / c
            ranges = np.where((t > 0) & (t < ranges), t, ranges)
        for wall in (-half_y, half_y):
            t = (wall - pose[1]) / s
            ranges = np.where((t > 0) & (t < ranges), t, ranges)
    ranges = ranges + rng.normal(0.0, noise, ranges.shape)
    return np.column_stack([ranges * np.cos(angles), ranges * np.sin(angles)])


def test_noisy_wall_refinement_is_not_held_at_its_start():
    """Paired with the nearest noisy point, a residual shrinks wherever the new scan already
    is, and the refined motion stays near its start. Measured from the walls' lines it does
    not: started 10 % short and 10 % long, a URG-like laser's refined forward motion moves
    by less than 3 % of that difference (the returns themselves: 5.7 %), and lands within
    1 % of the true 8 cm."""
    rng = np.random.default_rng(2)
    motion = np.array([0.08, 0.0, 0.0])
    ends = {"lines": {0.9: [], 1.1: []}, "points": {0.9: [], 1.1: []}}
    for _ in range(60):
        start = np.array([rng.uniform(-1.0, 0.5), rng.uniform(-0.8, 0.8), rng.uniform(-0.3, 0.3)])
        returns = _box_room_points(start, 0.03, rng)
        lines = reference_lines.ReferenceScan.from_points(returns, noise=0.03)
        # The same lines, paired with and measured from the returns themselves.
        normals, _, keep = reference_lines.line_decisions(returns, noise=0.03)
        points = reference_lines.ReferenceScan.of_kept(returns, normals, returns, keep)
        new = _box_room_points(se2.compose(start, motion), 0.03, rng)
        for name, reference in (("lines", lines), ("points", points)):
            for factor in (0.9, 1.1):
                z, used = point_to_line.refine(reference, new, motion * [factor, factor, 1.0])
                assert used > 200
                ends[name][factor].append(z[0])
    leak = {name: (np.mean(e[1.1]) - np.mean(e[0.9])) / (0.2 * motion[0]) for name, e in ends.items()}
    assert leak["lines"] < 0.03 < leak["points"]
    assert np.mean(ends["lines"][0.9] + ends["lines"][1.1]) == pytest.approx(motion[0], rel=0.01)


def _corridor_pair_errors(usable_range, draws=80, seed=3, cut=True, fit_noise=0.03):
    """Errors along the motion of refinements from the true motion, scans of a corridor whose
    end wall the first scan sees at the range limit: range_max 5 m, 3 cm noise, the driver
    drops readings past the limit (`cut`; without it they are kept, and the same seed
    draws the same noise); the robot drives 0.15 m toward that wall. `fit_noise`: the
    judged noise ReferenceScan.from_points is given (None: six-beam lines)."""
    from sclam_ros.sim.world import World

    range_max, sigma, step = 5.0, 0.03, 0.15
    world = World(np.array([[-2.0, -1.0, 8.0, -1.0], [-2.0, 1.0, 8.0, 1.0],  # side walls
                            [-2.0, -1.0, -2.0, 1.0],  # back wall, 2 m behind
                            [range_max - sigma, -3.0, range_max - sigma, 3.0]]))  # end wall
    angles = -np.pi + 2 * np.pi / 720 * np.arange(720)
    rng = np.random.default_rng(seed)

    def points(pose):
        ranges = world.raycast(pose, angles, 2 * range_max)
        ranges = ranges + rng.normal(0.0, sigma, ranges.shape)
        ok = ranges <= (range_max if cut else np.inf)  # the driver's cut, on the measured range
        return np.column_stack([ranges[ok] * np.cos(angles[ok]), ranges[ok] * np.sin(angles[ok])])

    motion = np.array([step, 0.0, 0.0])
    errors = []
    for _ in range(draws):
        reference = reference_lines.ReferenceScan.from_points(points(np.zeros(3)), fit_noise, usable_range)
        z, used = point_to_line.refine(reference, points(motion), motion)
        assert used > 100
        errors.append(z[0] - step)
    return np.array(errors)


def test_walls_at_the_range_limit_shorten_the_motion_less():
    """Of a wall at the limit only the returns whose noise brought them nearer are kept, so
    the first scan places it too near and the motion toward it comes out short. Against
    the same noise draws without the driver's cut: on lines fitted over six beams with
    nothing left out, the cut shortens the motion by 4-5 mm of 150 (seeds 1 and 3). With the
    clearance (ReferenceLinesConfig.clear_of_limit) judged by the anchors (where the beams meet the fitted
    lines, not where the noise put the returns) it costs nothing that 80 draws resolve
    (−0.5 to +0.4 mm, seeds 1-5)."""
    usable = 5.0 - CONFIG.reference_lines.clear_of_limit * 0.03
    plain = (_corridor_pair_errors(np.inf, fit_noise=None)
             - _corridor_pair_errors(np.inf, fit_noise=None, cut=False))
    protected = _corridor_pair_errors(usable) - _corridor_pair_errors(np.inf, cut=False)
    assert plain.mean() < -5 * plain.std() / np.sqrt(len(plain))  # the effect is there
    assert abs(protected.mean()) < 0.2 * abs(plain.mean())


@pytest.mark.parametrize("fit_noise,range_noise", [(None, 0.01), (0.03, 0.03)])
def test_refinement_does_not_depend_on_the_beam_order(fit_noise, range_noise):
    """A scene mirrored across the laser's x axis, its returns in reversed order (so still
    counter-clockwise), gives the mirrored motion and covariance. A decision that looked at
    the next beam but not the previous one would turn every match the same way: a laser
    yaw bias that no recording could reveal. (The six-beam fit of a 1 cm laser and the wide
    fit of a 3 cm one, with its range-limit clearance.)"""
    world = office_world()
    rng = np.random.default_rng(5)
    usable = 20.0 - CONFIG.reference_lines.clear_of_limit * range_noise if fit_noise else np.inf
    flip, flip_xy = np.array([1.0, -1.0, -1.0]), np.array([1.0, -1.0])
    for start in ([6.0, 3.0, 0.3], [3.0, 7.75, 0.0], [12.0, 12.5, 2.0]):
        motion = np.array([0.15, 0.01, 0.05])
        first = scan_points(world, np.array(start), range_noise, rng)
        second = scan_points(world, se2.compose(np.array(start), motion), range_noise, rng)
        answers = []
        for a, b, z0 in ((first, second, motion), (first[::-1] * flip_xy, second[::-1] * flip_xy, motion * flip)):
            reference = reference_lines.ReferenceScan.from_points(a, fit_noise, usable, small_objects=True)
            answers.append(point_to_line.refine_with_covariance(reference, b, z0))
        (z, used, covariance), (z_mirrored, used_mirrored, covariance_mirrored) = answers
        assert used > 100 and used_mirrored == used
        np.testing.assert_allclose(z_mirrored * flip, z, atol=1e-9)
        np.testing.assert_allclose(covariance_mirrored * np.outer(flip, flip), covariance, rtol=1e-6, atol=1e-15)


def _oblique_wall(spacing, first_bearing, count, offset=0.0):
    """Returns of the wall y = 8 m (normal +y) on beams `spacing` rad apart from
    `first_bearing`, beam k at first_bearing + (k + offset)·spacing: seen at a glancing
    angle, the beams hit it tens of cm apart."""
    bearing = first_bearing + (np.arange(count) + offset) * spacing
    return np.column_stack([8.0 / np.tan(bearing), np.full(count, 8.0)])


def test_pairs_along_a_sparsely_sampled_wall_reach_between_its_returns():
    """A new point halfway between two reference returns on a wall seen at a glancing angle
    (its returns 0.3-1.9 m apart) lies more than max_pair_distance from both: within a circle
    it is paired only if a return's own noise happens to bring it nearer. Gated along the
    wall by the beams' spacing there it is paired, and across the wall the gate stays
    max_pair_distance."""
    spacing = np.radians(1.0)
    reference_points = _oblique_wall(spacing, np.radians(16.0), 27)
    halfway = _oblique_wall(spacing, np.radians(16.0), 26, offset=0.5)
    gaps = np.hypot(*np.diff(reference_points, axis=0).T)
    assert gaps.min() > 2 * CONFIG.pairing.max_pair_distance
    circle = reference_lines.ReferenceScan.from_points(reference_points)
    ellipse = reference_lines.ReferenceScan.from_points(reference_points, beam_spacing=spacing)
    assert circle.reach is None
    z0 = np.zeros(3)
    assert point_to_line.refine(circle, halfway, z0)[1] < 20  # too few pairs: not refined
    z, used = point_to_line.refine(ellipse, halfway, z0)
    assert used >= 20 and np.allclose(z[1:], 0.0, atol=1e-6)
    # Off the wall by more than max_pair_distance: not paired, however sparse the beams.
    off_wall = halfway + [0.0, 1.2 * CONFIG.pairing.max_pair_distance]
    assert point_to_line.refine(ellipse, off_wall, z0)[1] == 0


def test_pairing_along_lines_changes_nothing_where_the_beams_are_dense():
    """Near walls (beams a few cm apart) the ellipse is the circle: the same motion."""
    world = office_world()
    rng = np.random.default_rng(7)
    start = np.array([6.0, 3.0, 0.3])
    motion = np.array([0.03, 0.01, 0.05])
    points = scan_points(world, start, 0.01, rng)
    new = scan_points(world, se2.compose(start, motion), 0.01, rng)
    near = np.hypot(points[:, 0], points[:, 1]) < 3.0
    near_new = np.hypot(new[:, 0], new[:, 1]) < 3.0
    circle = reference_lines.ReferenceScan.from_points(points[near])
    ellipse = reference_lines.ReferenceScan.from_points(points[near], beam_spacing=np.radians(1.0))
    assert np.all(ellipse.reach == CONFIG.pairing.max_pair_distance)
    z_circle, _ = point_to_line.refine(circle, new[near_new], motion + 0.01)
    z_ellipse, _ = point_to_line.refine(ellipse, new[near_new], motion + 0.01)
    assert np.allclose(z_circle, z_ellipse, atol=1e-9)


def test_refinement_weighed_by_a_growing_range_noise_is_unbiased_and_tighter():
    """A 12 m × 3 m hall seen from 1.5 m before one end by a 360° laser whose range noise
    grows with range (2 cm + 1 % of range) in the new scan, the reference's lines exact:
    weighed by 1/σ² of the range at which each point's beam meets its line (growth 0.5/m,
    as judged), the refined forward motion is unbiased (within 3 standard errors of the true
    15 cm) and scatters less than with every point weighed alike (Gauss-Markov): the near
    end wall's returns are the quieter."""
    rng = np.random.default_rng(8)
    room = dict(half_x=6.0, half_y=1.5, angles=ANGLES)
    start, motion = np.array([4.5, 0.3, 0.05]), np.array([-0.15, 0.0, 0.0])
    clean = _box_room_points(start, 0.0, rng, **room)
    errors = {0.0: [], 0.5: []}
    for growth, found in errors.items():
        reference = reference_lines.ReferenceScan.from_points(clean, 0.05, growth=growth)
        draws = np.random.default_rng(9)
        for _ in range(150):
            new = _box_room_points(se2.compose(start, motion), 0.0, draws, **room)
            ranges = np.hypot(new[:, 0], new[:, 1])
            new = new * (1.0 + draws.normal(0.0, 1.0, len(new)) * (0.02 + 0.01 * ranges)
                         / ranges)[:, None]
            z, used, _ = point_to_line.refine_with_covariance(reference, new, motion)
            assert used > 200
            found.append(z[0] - motion[0])
    alike, weighed = np.array(errors[0.0]), np.array(errors[0.5])
    assert abs(weighed.mean()) < 3 * weighed.std() / np.sqrt(len(weighed))
    assert weighed.std() < 0.95 * alike.std()  # 3.9 against 4.2 mm on these draws
