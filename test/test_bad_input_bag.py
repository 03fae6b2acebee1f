"""A real rosbag2 full of the surprises real robots record: the calibration must survive
them, count every rejection, and still land near the truth."""
import math
from collections import Counter

import numpy as np
import pytest

from sclam_ros.io import bag
from sclam_ros.core.estimator import calibrate_keyframes
from sclam_ros.core.inputs import Scan
from sclam_ros.io.messages import MessageRejected, check_scan, laser_scan_to_scan
from sclam_ros.io.recording import read_recording
from sclam_ros.core.params import CALIBRATION_KEYS, SclamParams
from sclam_ros.sim import simulate

WRAP = 65536.0


@pytest.fixture(scope="module")
def clean(tmp_path_factory):
    base = tmp_path_factory.mktemp("clean") / "bag"
    return base, simulate(base, robot="custom", duration=100.0, seed=4)


@pytest.fixture(scope="module")
def corrupted(clean, tmp_path_factory):
    base, truth = clean
    out = tmp_path_factory.mktemp("bad") / "bag"
    rng = np.random.default_rng(0)
    with bag.BagWriter(out, storage="sqlite3") as writer:
        js_count = scan_count = 0
        for topic, t, msg in bag.iter_messages(base, ["/joint_states", "/scan"]):
            stamp = msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec
            if topic == "/joint_states":
                js_count += 1
                # A 16-bit encoder counter: positions wrap at 65536 ticks.
                positions = [p % WRAP for p in msg.position]
                writer.write_joint_state(topic, stamp, list(msg.name), positions, record_time_s=t)
                if js_count % 97 == 0:  # a message from another driver: wrong joint names
                    writer.write_joint_state(topic, stamp + 1e-4, ["caster", "arm"], [0.0, 1.0], record_time_s=t)
                if js_count % 89 == 0:  # NaN positions
                    writer.write_joint_state(topic, stamp + 2e-4, list(msg.name), [math.nan, 1.0], record_time_s=t)
                if js_count % 83 == 0:  # the same sample twice
                    writer.write_joint_state(topic, stamp, list(msg.name), positions, record_time_s=t)
                if js_count % 79 == 0:  # a stale sample from the past
                    writer.write_joint_state(topic, stamp - 0.05, list(msg.name), positions, record_time_s=t)
            else:
                scan_count += 1
                ranges = np.array(msg.ranges, float)
                if scan_count % 53 == 0:
                    ranges[:] = np.inf  # all beams without return
                elif scan_count % 59 == 0:
                    ranges = np.array([], float)  # an empty scan
                else:
                    holes = rng.random(len(ranges)) < 0.1
                    ranges[holes] = rng.choice([0.0, np.nan, 1e6], holes.sum())  # 0/NaN/beyond max
                writer.write_scan(topic, Scan(stamp, ranges, msg.angle_min, msg.angle_increment,
                                              msg.range_min, msg.range_max, 0.0, msg.header.frame_id),
                                  record_time_s=t)
    params = SclamParams.from_yaml(base / "params.yaml")
    params.encoder_wrap = WRAP
    return out, params, truth


def test_survives_counts_and_stays_accurate(corrupted):
    path, params, truth = corrupted
    recording = read_recording(path, params)
    counts = recording.rejections.counts
    for reason in ("joint_state_missing_joint", "joint_state_non_finite", "encoder_duplicate_stamp",
                   "encoder_non_monotonic", "scan_empty"):
        assert any(reason in key for key in counts), (reason, dict(counts))
    result = calibrate_keyframes(recording.keyframes, params, recording.rejections)
    for key in CALIBRATION_KEYS:
        assert math.isfinite(result.estimate[key]) and math.isfinite(result.sigma[key])
        assert abs(result.estimate[key] - truth[key]) < 4 * result.sigma[key], key
    assert abs(result.estimate["wheel_base"] - truth["wheel_base"]) / truth["wheel_base"] < 0.01


def test_a_bag_rejects_each_bad_scan_as_the_node_does(clean, tmp_path):
    """One gate (io/messages.check_scan after laser_scan_to_scan, as ros/node.py's _on_scan
    applies them): the bag path counts the same messages under the same reasons."""
    base, _ = clean
    out = tmp_path / "bag"
    with bag.BagWriter(out, storage="sqlite3") as writer:
        for n, (topic, t, msg) in enumerate(bag.iter_messages(base, ["/joint_states", "/scan"])):
            stamp = msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec
            if topic == "/joint_states":
                writer.write_joint_state(topic, stamp, list(msg.name), list(msg.position), record_time_s=t)
                continue
            ranges, angle_min, increment = np.array(msg.ranges, float), msg.angle_min, msg.angle_increment
            if n % 41 == 0:
                ranges = np.array([], float)  # empty
            elif n % 43 == 0:
                increment = 0.0  # every beam in one direction
            elif n % 47 == 0:
                angle_min = math.nan
            writer.write_scan(topic, Scan(stamp, ranges, angle_min, increment, msg.range_min,
                                          msg.range_max, 0.0, msg.header.frame_id), record_time_s=t)
    live = Counter()
    for _, _, msg in bag.iter_messages(out, ["/scan"]):
        try:
            check_scan(laser_scan_to_scan(msg))
        except MessageRejected as exc:
            live[exc.reason] += 1
    assert set(live) == {"scan_empty", "scan_zero_angle_increment", "scan_non_finite_angles"}
    params = SclamParams.from_yaml(base / "params.yaml")
    counts = read_recording(out, params).rejections.counts
    assert {reason: counts.get(reason, 0) for reason in live} == dict(live)
    # A stamp no bag can hold (header stamps are integers), the same gate's reason:
    with pytest.raises(MessageRejected) as rejected:
        check_scan(Scan(math.nan, np.ones(3), 0.0, 0.1, 0.1, 10.0))
    assert rejected.value.reason == "scan_non_finite_stamp"


def test_standing_still_is_a_clear_error_not_a_nan(tmp_path):
    """No motion at all: nothing is observable. The answer must say so, not invent numbers."""
    from sclam_ros.sim.world import office_world

    world = office_world()
    angles = -np.pi + 2 * np.pi / 360 * np.arange(360)
    pose = np.array([6.0, 3.0, 0.0])
    out = tmp_path / "still"
    with bag.BagWriter(out) as writer:
        for i in range(300):
            t = 1000.0 + 0.02 * i
            writer.write_joint_state("/joint_states", t, ["left_wheel_joint", "right_wheel_joint"], [5.0, 7.0])
            if i % 5 == 0:
                ranges = world.raycast(pose, angles, 20.0)
                writer.write_scan("/scan", Scan(t + 0.003, ranges, -np.pi, 2 * np.pi / 360, 0.05, 20.0))
    params = SclamParams(ticks_per_revolution=1000, wheel_radius_left=0.1, wheel_radius_right=0.1,
                         wheel_base=0.5)
    recording = read_recording(out, params)
    result = calibrate_keyframes(recording.keyframes, params, recording.rejections)
    for key in CALIBRATION_KEYS:
        assert math.isfinite(result.estimate[key])
        assert not result.observable[key], key
        assert result.estimate[key] == pytest.approx(getattr(params, key), abs=1e-3)


def test_straight_line_only_flags_what_it_cannot_see(tmp_path):
    """Driving straight down a corridor excites no rotation: the wheel base and the laser
    offset are not observable and must come back at nominal, flagged, finite."""
    from sclam_ros.core import se2
    from sclam_ros.sim.world import office_world

    world = office_world()
    angles = -np.pi + 2 * np.pi / 360 * np.arange(360)
    radius, ticks, speed = 0.1, 4000.0, 0.4
    mount = np.array([0.2, 0.0, 0.0])
    rng = np.random.default_rng(1)
    out = tmp_path / "straight"
    with bag.BagWriter(out) as writer:
        for i in range(50 * 40):  # 40 s at 50 Hz encoders
            t = 1000.0 + 0.02 * i
            travelled = speed * (t - 1000.0)
            tick = math.floor(travelled / radius * ticks / (2 * np.pi))
            writer.write_joint_state("/joint_states", t, ["left_wheel_joint", "right_wheel_joint"],
                                     [float(tick), float(tick)])
            if i % 5 == 2:
                laser = se2.compose(np.array([2.0 + travelled, 7.75, 0.0]), mount)
                ranges = world.raycast(laser, angles, 20.0) + rng.normal(0, 0.01, 360)
                writer.write_scan("/scan", Scan(t, ranges, -np.pi, 2 * np.pi / 360, 0.05, 20.0))
    params = SclamParams(ticks_per_revolution=ticks, wheel_radius_left=0.1, wheel_radius_right=0.1,
                         wheel_base=0.5, laser_x=0.15)
    recording = read_recording(out, params)
    result = calibrate_keyframes(recording.keyframes, params, recording.rejections)
    for key in CALIBRATION_KEYS:
        assert math.isfinite(result.estimate[key]) and math.isfinite(result.sigma[key])
    for key in ("wheel_base", "laser_x", "laser_y"):
        assert not result.observable[key], key
        assert result.estimate[key] == pytest.approx(getattr(params, key), abs=1e-6)
