"""The simulator: geometry, kinematic consistency of encoders and truth, effects, output."""
import json

import numpy as np
import pytest

from sclam_ros.core import se2
from sclam_ros.io.bag import iter_messages, topic_info
from sclam_ros.cli import simulate as simulate_command
from sclam_ros.core.params import CALIBRATION_KEYS, SclamParams
from sclam_ros.sim import simulate
from sclam_ros.sim.effects import EFFECTS, EffectSet, make_effect
from sclam_ros.sim.motion import Trajectory, TrueKinematics, twist_increment
from sclam_ros.sim.robots import PRESETS
from sclam_ros.sim.trajectory import simulate_trajectory
from sclam_ros.sim.sensors import LaserModel
from sclam_ros.sim.world import (CORRIDORS, MIRRORED, SCENES, cast_rays, distance_to_segments, office_world,
                                  outdoor_world, scene_world)

WORLD = office_world()


# --- independent oracles (deliberately not the simulator's own code) ------------------


def yaw_of(q):
    return np.arctan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y**2 + q.z**2))


def segments_cross(p, q, segments):
    """Whether segment p→q properly crosses any wall, by orientation tests."""
    a, b = segments[:, :2], segments[:, 2:]

    def orient(u, v, w):
        return np.sign((v[..., 0] - u[..., 0]) * (w[..., 1] - u[..., 1])
                       - (v[..., 1] - u[..., 1]) * (w[..., 0] - u[..., 0]))

    return bool(np.any((orient(p, q, a) * orient(p, q, b) < 0) & (orient(a, b, p) * orient(a, b, q) < 0)))


def dead_reckoning(left, right, r_left, r_right, base):
    """Exact-arc integration of wheel angle samples (N, ) each; poses (N, 3) from identity."""
    dl, dr = np.diff(left) * r_left, np.diff(right) * r_right
    ds, dth = (dl + dr) / 2.0, (dr - dl) / base
    theta = np.concatenate([[0.0], np.cumsum(dth)])
    chord = ds * np.sinc(dth / 2.0 / np.pi)  # np.sinc is sin(πx)/(πx)
    x = np.concatenate([[0.0], np.cumsum(chord * np.cos(theta[:-1] + dth / 2.0))])
    y = np.concatenate([[0.0], np.cumsum(chord * np.sin(theta[:-1] + dth / 2.0))])
    return np.stack([x, y, theta], -1)


def truth_at(stamps, truth_t, gt):
    """Ground truth at scan stamps by linear interpolation between encoder-rate samples:
    exact in θ (constant ω per 20 ms) and within ~0.1 mm in position."""
    theta = np.unwrap(gt[:, 2])
    return np.stack([np.interp(stamps, truth_t, gt[:, 0]), np.interp(stamps, truth_t, gt[:, 1]),
                     np.interp(stamps, truth_t, theta)], -1)


def read_bag(path):
    ticks, enc_t, truth, truth_t, scans = [], [], [], [], []
    for topic, t, msg in iter_messages(path, ["/joint_states", "/ground_truth/odom", "/scan"]):
        if topic == "/joint_states":
            enc_t.append(msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9)
            ticks.append(np.array(msg.position))
        elif topic == "/ground_truth/odom":
            truth_t.append(msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9)
            p = msg.pose.pose
            truth.append((p.position.x, p.position.y, yaw_of(p.orientation)))
        else:
            scans.append(msg)
    return np.array(enc_t), np.array(ticks), np.array(truth_t), np.array(truth), scans


@pytest.fixture(scope="module")
def noise_free(tmp_path_factory):
    """60 s of PowerBot without slip or range noise: encoders must match the truth exactly."""
    out = tmp_path_factory.mktemp("sim") / "noise_free"
    truth = simulate(out, duration=60.0, seed=1, slip_noise=0.0, range_noise=0.0)
    return out, truth, read_bag(out)


@pytest.fixture(scope="module")
def default_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("sim") / "default"
    truth = simulate(out, robot="pioneer", duration=60.0, seed=2, storage="mcap")
    return out, truth, read_bag(out)


# --- world ------------------------------------------------------------------------------


def test_raycast_in_rectangle_matches_analytic_distances():
    width, height = 4.0, 2.0
    box = np.array([[0, 0, width, 0], [width, 0, width, height], [width, height, 0, height],
                    [0, height, 0, 0]], float)
    origin = np.array([1.0, 0.5])
    angles = np.linspace(-np.pi, np.pi, 721)[:-1]
    ranges = cast_rays(box, np.broadcast_to(origin, (len(angles), 2)), angles, 100.0)
    c, s = np.cos(angles), np.sin(angles)
    with np.errstate(divide="ignore"):
        to_x = np.where(c > 0, (width - origin[0]) / c, np.where(c < 0, -origin[0] / c, np.inf))
        to_y = np.where(s > 0, (height - origin[1]) / s, np.where(s < 0, -origin[1] / s, np.inf))
    np.testing.assert_allclose(ranges, np.minimum(to_x, to_y), rtol=1e-12)
    # The World wrapper: the same beams from a rotated pose are the rotated answer.
    from sclam_ros.sim.world import World

    rotated = World(box).raycast((1.0, 0.5, 0.3), angles - 0.3, 100.0)
    np.testing.assert_allclose(rotated, ranges, rtol=1e-12)
    # Out of range and open space give inf.
    assert np.all(np.isinf(cast_rays(box, [[1.0, 0.5]], [0.0], 2.0)))
    assert np.all(np.isinf(cast_rays(box[:1], [[1.0, 0.5]], [np.pi / 2], 100.0)))


def test_office_rays_stop_at_the_first_wall():
    rng = np.random.default_rng(0)
    origins = np.array([WORLD.nodes[n] for n in WORLD.nodes])
    angles = rng.uniform(-np.pi, np.pi, (len(origins), 50))
    for origin, beam_angles in zip(origins, angles):
        ranges = WORLD.raycast((*origin, 0.0), beam_angles, 50.0)
        assert np.all(np.isfinite(ranges))  # the office is closed
        hits = origin + ranges[:, None] * np.stack([np.cos(beam_angles), np.sin(beam_angles)], -1)
        assert distance_to_segments(WORLD.segments, hits).max() < 1e-9
        for hit, r, a in zip(hits, ranges, beam_angles):
            short = origin + (r - 1e-6) * np.array([np.cos(a), np.sin(a)])
            assert not segments_cross(origin, short, WORLD.segments)


@pytest.mark.parametrize("scene", sorted(SCENES))
def test_roadmap_edges_are_clear_for_every_robot(scene):
    world = SCENES[scene]()
    margin = max(p.footprint_radius for p in PRESETS.values()) + 0.3
    for a, b in world.edges:
        pa, pb = np.array(world.nodes[a]), np.array(world.nodes[b])
        points = pa + np.linspace(0, 1, 400)[:, None] * (pb - pa)
        assert world.clearance(points).min() >= margin, (a, b)
        assert world.inside_bounds(points).all(), (a, b)
    for node in world.nodes:
        assert world.neighbours(node), node
    assert set(world.open_nodes) <= set(world.nodes)


@pytest.mark.parametrize("scene", sorted(SCENES))
def test_a_mirrored_scene_is_seen_mirrored(scene):
    """The scene reflected across its x axis: a laser at the reflected pose sees at the
    reflected bearings exactly what it saw; the roadmap is reflected with it."""
    world, mirror = scene_world(scene), scene_world(scene + MIRRORED)
    rng = np.random.default_rng(2)
    angles = np.linspace(-np.pi, np.pi, 360, endpoint=False)
    for name in rng.choice(sorted(world.nodes), 5, replace=False):
        x, y = world.nodes[name]
        assert mirror.nodes[name] == (x, -y)
        heading = rng.uniform(-np.pi, np.pi)
        np.testing.assert_allclose(mirror.raycast(np.array([x, -y, -heading]), -angles, 20.0),
                                   world.raycast(np.array([x, y, heading]), angles, 20.0), atol=1e-9)
    assert mirror.edges == world.edges and mirror.open_nodes == world.open_nodes
    assert mirror.inside_bounds(np.array([[x, -y] for x, y in world.nodes.values()])).all()
    with pytest.raises(ValueError, match="unknown scene"):
        scene_world("moon" + MIRRORED)


def test_outdoor_scene_has_few_long_lines():
    """What makes it outdoor for a scan matcher: many short segments (trunks, poles, cars),
    almost no long walls, and most of a 20 m laser's beams without a return."""
    world = outdoor_world()
    lengths = np.hypot(world.segments[:, 2] - world.segments[:, 0], world.segments[:, 3] - world.segments[:, 1])
    assert (lengths > 5.0).sum() <= 3 and np.median(lengths) < 1.0
    angles = np.linspace(-np.pi, np.pi, 360, endpoint=False)
    ranges = world.raycast(np.array([15.0, 8.0, 0.3]), angles, 20.0)
    assert 0.05 < np.isfinite(ranges).mean() < 0.5


def test_corridors_scene_is_bare_along_its_corridors():
    """What makes the corridors scene hard for a short-range laser: in the middle of its
    long corridors a 5.6 m laser sees the two side walls only, and nothing ahead or behind;
    the corridor bands (CORRIDORS) are the corridors: 1.2 m from both walls along their
    centre lines."""
    world = SCENES["corridors"]()
    angles = np.linspace(-np.pi, np.pi, 720, endpoint=False)
    for pose, across in (((14.0, 2.5, 0.0), 1), ((14.0, 15.5, np.pi), 1), ((2.5, 9.0, 0.5 * np.pi), 0)):
        ranges = world.raycast(np.array(pose), angles, 5.6)
        hit = np.isfinite(ranges)
        assert 0.5 < hit.mean() < 0.95  # the ends of the corridor are out of range
        bearing = angles[hit] + pose[2]
        points = np.column_stack((pose[0] + ranges[hit] * np.cos(bearing),
                                  pose[1] + ranges[hit] * np.sin(bearing)))
        # every return on a side wall: 1.2 m across the corridor from its centre line
        np.testing.assert_allclose(np.abs(points[:, across] - pose[across]), 1.2, atol=1e-9)
    for (x0, x1), (y0, y1), axis in CORRIDORS["corridors"]:
        along = np.linspace(x0, x1, 20) if axis == 0 else np.linspace(y0, y1, 20)
        middle = np.full(20, 0.5 * (y0 + y1) if axis == 0 else 0.5 * (x0 + x1))
        centre_line = np.column_stack((along, middle) if axis == 0 else (middle, along))
        np.testing.assert_allclose(world.clearance(centre_line[1:-1]), 1.2, atol=1e-9)


# --- motion and trajectory ---------------------------------------------------------------


def test_twist_increment_matches_fine_integration():
    for vx, vy, w in [(0.5, 0.0, 0.8), (0.3, 0.05, -1.0), (0.4, 0.0, 1e-7), (0.0, 0.0, 1.0)]:
        exact = twist_increment(vx, vy, w, 0.7)
        n = 100_000
        dt = 0.7 / n
        theta = w * dt * np.arange(n) + w * dt / 2
        fine = [np.sum(vx * np.cos(theta) - vy * np.sin(theta)) * dt,
                np.sum(vx * np.sin(theta) + vy * np.cos(theta)) * dt, w * 0.7]
        np.testing.assert_allclose(exact, fine, atol=1e-9)


def test_pose_at_is_continuous_and_hits_knots():
    kin = TrueKinematics(0.1263, 0.1275, 0.5825)
    trajectory = simulate_trajectory(WORLD, kin, 30.0, seed=5, robot_radius=0.45)
    np.testing.assert_allclose(trajectory.pose_at(trajectory.knot_times, unwrapped=True), trajectory.poses,
                               atol=1e-12)
    t = np.arange(0.0, 30.0, 0.001)
    poses = trajectory.pose_at(t, unwrapped=True)
    # No jumps: 1 ms steps move at most v_max·1 ms and turn at most ω_max·1 ms.
    steps = np.diff(poses, axis=0)
    assert np.hypot(steps[:, 0], steps[:, 1]).max() <= 0.6e-3 + 1e-12
    assert np.abs(steps[:, 2]).max() <= 1.0e-3 + 1e-12
    with pytest.raises(ValueError):
        trajectory.pose_at(31.0)


@pytest.mark.parametrize("robot,seed,scene", [("powerbot", 0, "office"), ("custom", 1, "office"),
                                              ("pioneer", 2, "office"), ("powerbot", 7, "office"),
                                              ("powerbot", 3, "outdoor"), ("custom", 4, "outdoor"),
                                              ("powerbot", 5, "corridors"), ("pioneer", 6, "corridors")])
def test_trajectory_stays_in_free_space_and_within_limits(robot, seed, scene):
    preset = PRESETS[robot]
    world = SCENES[scene]()
    kin = TrueKinematics(*(preset.true[k] for k in CALIBRATION_KEYS[:3]))
    trajectory = simulate_trajectory(world, kin, 240.0, seed, preset.footprint_radius)
    t = np.arange(0.0, trajectory.duration, 0.005)
    positions = trajectory.pose_at(t)[:, :2]
    assert world.inside_bounds(positions).all()
    assert world.clearance(positions).min() > preset.footprint_radius
    # The path between samples cannot cross a wall either.
    assert not any(segments_cross(p, q, world.segments) for p, q in zip(positions[:-1:20], positions[20::20]))
    v, w = trajectory.twists[:, 0], trajectory.twists[:, 2]
    assert v.min() >= 0.0 and v.max() <= 0.6 + 1e-9 and np.abs(w).max() <= 1.0 + 1e-9
    assert np.abs(np.diff(v)).max() / trajectory.dt <= 0.6 + 1e-6  # smooth accelerations
    assert np.abs(np.diff(w)).max() / trajectory.dt <= 2.0 + 1e-6
    # Every parameter excited: both turn directions, turns on the spot, straights.
    assert (w > 0.3).mean() > 0.02 and (w < -0.3).mean() > 0.02
    # Turns on the spot: at the dead ends of the office's and the outdoor scene's roadmaps
    # and at some corners; a ring of corridors has no dead ends, so there they come only
    # from the lobbies' manoeuvres and random stops and may be rarer.
    assert ((v < 0.01) & (np.abs(w) > 0.5)).mean() > (0.0 if scene == "corridors" else 0.01)
    assert ((v > 0.2) & (np.abs(w) < 0.02)).mean() > 0.1
    assert np.abs(v).sum() * trajectory.dt > 0.2 * 240.0


# --- sensors and the recorded bag ---------------------------------------------------------


def test_bag_layout_params_and_truth(noise_free):
    out, truth, _ = noise_free
    assert (out / "metadata.yaml").is_file() and (out / "params.yaml").is_file()
    info = topic_info(out)
    assert info["/joint_states"] == ("sensor_msgs/msg/JointState", 3001)
    assert info["/ground_truth/odom"] == ("nav_msgs/msg/Odometry", 3001)
    assert info["/scan"] == ("sensor_msgs/msg/LaserScan", 600)
    params = SclamParams.from_yaml(out / "params.yaml")
    assert params.calibration() == PRESETS["powerbot"].nominal
    assert params.ticks_per_revolution == 22835 and params.joint_states_topic == "/joint_states"
    saved = json.loads((out / "truth.json").read_text())
    assert saved == truth
    assert {k: saved[k] for k in CALIBRATION_KEYS} == PRESETS["powerbot"].true
    assert saved["robot"] == "powerbot" and saved["seed"] == 1 and saved["effects"] == {}


def test_encoders_reproduce_ground_truth_without_slip(noise_free):
    _, truth, (enc_t, ticks, truth_t, gt, _) = noise_free
    np.testing.assert_allclose(enc_t, truth_t, atol=1e-6)
    assert np.all(ticks == np.floor(ticks)) and np.all(np.diff(ticks, axis=0)[np.abs(gt[1:, 0]) > 0] is not None)
    angles = (ticks - ticks[0]) * 2 * np.pi / truth["ticks_per_revolution"]
    poses = dead_reckoning(angles[:, 0], angles[:, 1], truth["wheel_radius_left"],
                           truth["wheel_radius_right"], truth["wheel_base"])
    np.testing.assert_allclose(gt[0], 0.0, atol=1e-12)  # REP-105: odom is the start pose
    # Only tick quantisation remains: 2π/22835 rad of wheel, ~35 µm of travel, per sample.
    assert np.hypot(*(poses[:, :2] - gt[:, :2]).T).max() < 2e-3
    assert np.abs(se2.wrap_angle(poses[:, 2] - gt[:, 2])).max() < np.radians(0.05)
    # Driving forward increases both counters.
    forward = np.diff(gt[:, 0]) * np.cos(gt[:-1, 2]) + np.diff(gt[:, 1]) * np.sin(gt[:-1, 2]) > 1e-3
    assert np.all(np.diff(ticks, axis=0)[forward].sum(axis=0) > 0)


def test_encoders_within_slip_budget(default_run):
    _, truth, (_, ticks, _, gt, _) = default_run
    angles = (ticks - ticks[0]) * 2 * np.pi / truth["ticks_per_revolution"]
    poses = dead_reckoning(angles[:, 0], angles[:, 1], truth["wheel_radius_left"],
                           truth["wheel_radius_right"], truth["wheel_base"])
    slip = truth["sensors"]["slip_noise"]
    turned = np.abs(np.diff(angles, axis=0)).sum(axis=0)
    # Heading error of a random walk on both wheels: σ = slip·sqrt(r_l²Φ_l + r_r²Φ_r)/b.
    sigma = slip * np.sqrt(truth["wheel_radius_left"] ** 2 * turned[0]
                           + truth["wheel_radius_right"] ** 2 * turned[1]) / truth["wheel_base"]
    heading_error = np.abs(np.unwrap(poses[:, 2]) - np.unwrap(gt[:, 2])).max()
    assert heading_error < 5 * sigma
    assert heading_error > 1e-4  # slip noise is really there


def test_laser_sees_walls_only_never_through_them(noise_free):
    _, truth, (_, _, truth_t, gt, scans) = noise_free
    origin = np.array(truth["odom_origin_in_world"])
    mount = np.array([truth[k] for k in ("laser_x", "laser_y", "laser_yaw")])
    for scan in scans[::25]:
        stamp = scan.header.stamp.sec + scan.header.stamp.nanosec * 1e-9
        # Ground truth is at the encoder rate; the scan lies between two samples.
        k = np.searchsorted(truth_t, stamp)
        assert truth_t[k - 1] < stamp < truth_t[k]
        body = se2.compose(origin, truth_at(stamp, truth_t, gt))
        laser = se2.compose(body, mount)
        ranges = np.asarray(scan.ranges, float)
        angles = scan.angle_min + scan.angle_increment * np.arange(len(ranges))
        assert scan.header.frame_id == "laser" and len(ranges) == 360
        assert scan.angle_min == pytest.approx(-np.pi) and scan.angle_increment == pytest.approx(2 * np.pi / 360)
        finite = np.isfinite(ranges)
        assert finite.mean() > 0.9 and np.all(ranges[finite] <= 20.0)
        hits = laser[:2] + ranges[finite, None] * np.stack(
            [np.cos(laser[2] + angles[finite]), np.sin(laser[2] + angles[finite])], -1)
        assert distance_to_segments(WORLD.segments, hits).max() < 2e-3
        for hit in hits[::10]:
            inner = laser[:2] + 0.95 * (hit - laser[:2])
            assert not segments_cross(laser[:2], inner, WORLD.segments)


def test_range_noise_level(default_run):
    out, truth, (_, _, truth_t, gt, scans) = default_run
    # Compare with a noise-free cast from the true laser pose.
    origin = np.array(truth["odom_origin_in_world"])
    mount = np.array([truth[k] for k in ("laser_x", "laser_y", "laser_yaw")])
    residuals = []
    for scan in scans[::5]:
        stamp = scan.header.stamp.sec + scan.header.stamp.nanosec * 1e-9
        laser = se2.compose(se2.compose(origin, truth_at(stamp, truth_t, gt)), mount)
        angles = scan.angle_min + scan.angle_increment * np.arange(len(scan.ranges))
        expected = WORLD.raycast(laser, angles, 20.0)
        ok = np.isfinite(expected) & np.isfinite(scan.ranges) & (expected < 19.9)
        residuals.append(np.asarray(scan.ranges, float)[ok] - expected[ok])
    residuals = np.concatenate(residuals)
    assert len(residuals) > 1000
    assert np.std(residuals) == pytest.approx(truth["sensors"]["range_noise"], rel=0.1)
    assert abs(np.mean(residuals)) < 0.002


def test_laser_model_geometry_and_noise():
    """Field of view and beam angles as a LaserScan describes them; noise, dropouts and mixed
    pixels measured against what the model says."""
    rng = np.random.default_rng(0)
    wide = LaserModel(beams=1081, fov=np.radians(270.0))
    angles = wide.angles()
    assert angles[0] == pytest.approx(-np.radians(135.0)) and angles[-1] == pytest.approx(np.radians(135.0))
    full = LaserModel(beams=360)
    assert full.angle_min == -np.pi and full.angles()[-1] == pytest.approx(np.pi - np.radians(1.0))
    with pytest.raises(ValueError, match="field of view"):
        LaserModel(fov=np.radians(400.0))
    true = np.full((200, 1000), 10.0)
    noisy = LaserModel(range_noise=0.01, range_noise_per_m=0.002).measure(true, rng)
    assert np.std(noisy - true) == pytest.approx(0.01 + 0.002 * 10.0, rel=0.02)
    dropped = LaserModel(range_noise=0.0, dropout=0.3).measure(true, rng)
    assert np.isinf(dropped).mean() == pytest.approx(0.3, abs=0.01)
    # A depth edge every other beam: 2 m then 6 m. Mixed points lie between the surfaces.
    edges = np.tile([2.0, 6.0], (200, 500))
    mixed = LaserModel(range_noise=0.0, mixed_pixels=0.5).measure(edges, rng)
    phantom = (mixed != edges) & np.isfinite(mixed)
    assert phantom[:, :-1].mean() == pytest.approx(0.5, abs=0.02)
    assert ((mixed[phantom] > 2.0) & (mixed[phantom] < 6.0)).all()


def test_deterministic_per_seed(tmp_path):
    a = simulate(tmp_path / "a", duration=15.0, seed=3)
    b = simulate(tmp_path / "b", duration=15.0, seed=3, storage="mcap")
    c = simulate(tmp_path / "c", duration=15.0, seed=4)
    ra, rb, rc = read_bag(tmp_path / "a"), read_bag(tmp_path / "b"), read_bag(tmp_path / "c")
    assert {k: v for k, v in a.items() if k != "storage"} == {k: v for k, v in b.items() if k != "storage"}
    np.testing.assert_array_equal(ra[1], rb[1])
    np.testing.assert_array_equal(ra[3], rb[3])
    np.testing.assert_array_equal(np.array([s.ranges for s in ra[4]]), np.array([s.ranges for s in rb[4]]))
    assert not np.array_equal(ra[3], rc[3])


# --- effects ------------------------------------------------------------------------------


def test_effects_registry_and_parsing():
    assert set(EFFECTS) >= {"time_offset", "radius_change_at", "lateral_slip", "radius_drift", "scan_motion",
                            "wheel_eccentricity", "speed_dependent_slip", "floor_noise_region"}
    assert make_effect("time_offset", "0.05").offset == 0.05
    change = make_effect("radius_change_at", "10,-0.02,0.01")
    assert (change.time, change.left, change.right) == (10.0, -0.02, 0.01)
    described = make_effect("radius_change_at", "right:0.5,time:3").describe()
    assert {k: described[k] for k in ("time", "left", "right")} == {"time": 3.0, "left": -0.01, "right": 0.5}
    assert np.isnan(described["then_after"])  # no second step unless asked for
    with pytest.raises(ValueError, match="unknown effect"):
        make_effect("gremlins")
    with pytest.raises(ValueError, match="unknown parameter"):
        make_effect("time_offset", {"delay": 1.0})
    with pytest.raises(ValueError, match="not inside the run"):
        EffectSet.from_spec({"radius_change_at": 100}).for_duration(60.0)
    assert EffectSet.from_spec({"radius_change_at": None}).for_duration(60.0).effects[0].time == 30.0


def test_radius_steps_and_ramp_follow_their_definition():
    two = make_effect("radius_change_at", {"time": 10.0, "left": -0.01, "right": 0.02, "then_after": 5.0,
                                           "then_left": -0.01, "then_right": 0.0})
    left, right = two.radii(np.array([9.99, 10.0, 14.99, 15.0]), 0.1, 0.2)
    np.testing.assert_allclose(left, [0.1, 0.099, 0.099, 0.099 * 0.99])
    np.testing.assert_allclose(right, [0.2, 0.204, 0.204, 0.204])
    ramp = make_effect("radius_ramp", {"time": 100.0, "duration": 300.0, "left": -0.01, "right": 0.0})
    left, right = ramp.radii(np.array([0.0, 100.0, 250.0, 400.0, 900.0]), 0.1, 0.2)
    np.testing.assert_allclose(left, [0.1, 0.1, 0.0995, 0.099, 0.099])
    np.testing.assert_allclose(right, 0.2)
    with pytest.raises(ValueError, match="do not fit"):
        make_effect("radius_ramp", {"time": 50.0}).for_duration(40.0)


def test_radius_change_scales_wheel_rotation_after_the_step():
    plain = TrueKinematics(0.1263, 0.1275, 0.5825)
    changed = TrueKinematics(0.1263, 0.1275, 0.5825,
                             EffectSet.from_spec({"radius_change_at": (10.0, -0.01, -0.0033)}))
    trajectory = simulate_trajectory(WORLD, plain, 20.0, seed=0, robot_radius=0.45)
    before, after = plain.wheel_angle_increments(trajectory), changed.wheel_angle_increments(trajectory)
    k = int(round(10.0 / trajectory.dt))
    np.testing.assert_array_equal(before[:k], after[:k])
    np.testing.assert_allclose(after[k:], before[k:] / np.array([0.99, 0.9967]), rtol=1e-12)


def test_time_offset_shifts_encoder_stamps_only(tmp_path):
    truth = simulate(tmp_path / "bag", duration=5.0, seed=0, effects={"time_offset": 0.03})
    enc_t, _, truth_t, _, scans = read_bag(tmp_path / "bag")
    np.testing.assert_allclose(enc_t - truth_t, 0.03, atol=1e-6)
    first_scan = scans[0].header.stamp.sec + scans[0].header.stamp.nanosec * 1e-9
    assert first_scan == pytest.approx(truth["start_time"] + 0.013, abs=1e-6)
    assert truth["effects"] == {"time_offset": {"offset": 0.03}}


def test_lateral_slip_moves_the_body_sideways_in_turns():
    kin = TrueKinematics(0.1263, 0.1275, 0.5825, EffectSet.from_spec({"lateral_slip": 0.05}))
    trajectory = simulate_trajectory(WORLD, kin, 240.0, seed=0, robot_radius=0.45)
    vx, vy, w = trajectory.twists.T
    np.testing.assert_allclose(vy, -0.05 * vx * w)
    assert np.abs(vy).max() > 0.005  # curves driven at speed: loops, S-curves


def test_wheel_eccentricity_and_speed_slip_bend_the_wheel_rotation():
    plain = TrueKinematics(0.1263, 0.1275, 0.5825)
    trajectory = simulate_trajectory(WORLD, plain, 20.0, seed=0, robot_radius=0.45)
    before = plain.wheel_angle_increments(trajectory)
    ecc = TrueKinematics(0.1263, 0.1275, 0.5825, EffectSet.from_spec(
        {"wheel_eccentricity": {"amplitude": 0.02, "phase_left": 0.0, "phase_right": 0.0}}))
    after = ecc.wheel_angle_increments(trajectory)
    phi = np.vstack([np.zeros(2), np.cumsum(after, 0)[:-1]])
    # rolling distance preserved: r·(1 + a·sin φ)·dφ = r·dφ₀
    np.testing.assert_allclose(after * (1 + 0.02 * np.sin(phi)), before, rtol=1e-12, atol=1e-15)
    slip = TrueKinematics(0.1263, 0.1275, 0.5825, EffectSet.from_spec({"speed_dependent_slip": 0.1}))
    u = np.abs(trajectory.twists[:, 0])
    np.testing.assert_allclose(slip.wheel_angle_increments(trajectory),
                               before * (1 + 0.1 * u**2)[:, None], rtol=1e-12)


def test_floor_noise_region_scales_slip_noise_by_position():
    effect = EffectSet.from_spec({"floor_noise_region": {"factor": 3.0, "x_min": 1.0}})
    np.testing.assert_array_equal(effect.slip_noise_scale(np.array([[0.0, 5.0], [2.0, -1.0]])),
                                  [1.0, 3.0])


def test_scan_motion_writes_time_increment(tmp_path):
    simulate(tmp_path / "bag", duration=5.0, seed=0, effects=["scan_motion"])
    scans = read_bag(tmp_path / "bag")[4]
    assert scans[0].time_increment == pytest.approx(0.1 / 360)
    assert scans[0].scan_time == pytest.approx(0.1)


# --- command line ---------------------------------------------------------------------------


def test_cli_writes_a_bag_and_reports_errors(tmp_path, capsys):
    out = tmp_path / "run"
    code = simulate_command.main([str(out), "--robot", "custom", "--duration", "5", "--seed", "9",
                                  "--true", "wheel_base=0.71", "--effect", "time_offset=0.01",
                                  "--storage", "mcap", "--quiet"])
    assert code == 0
    truth = json.loads((out / "truth.json").read_text())
    assert truth["robot"] == "custom" and truth["wheel_base"] == 0.71 and truth["storage"] == "mcap"
    assert list(out.glob("*.mcap"))
    assert simulate_command.main([str(out), "--duration", "5", "--quiet"]) == 2
    assert "exists already" in capsys.readouterr().err
    assert simulate_command.main([str(tmp_path / "x"), "--true", "wheel_radius=1", "--quiet"]) == 2
    assert "unknown true value" in capsys.readouterr().err
    assert not (tmp_path / "x").exists()


def test_laser_range_resolution_reports_multiples_of_it():
    """A driver that rounds (the Freiburg benchmark's SICK logs: about 2.5-5 cm) reports
    multiples of the resolution; the rounding error is at most half a step."""
    true = np.linspace(0.5, 10.0, 400)[None, :]
    model = LaserModel(beams=400, range_noise=0.0, range_resolution=0.05, range_max=20.0)
    measured = model.measure(true, np.random.default_rng(1))
    np.testing.assert_allclose(measured / 0.05, np.round(measured / 0.05), atol=1e-9)
    assert np.abs(measured - true).max() <= 0.025 + 1e-12
    with pytest.raises(ValueError, match="range_resolution"):
        LaserModel(range_resolution=-0.01)
