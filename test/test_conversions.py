"""Message → core types, for rosbags-deserialised and rclpy messages alike."""
import math

import numpy as np
import pytest
from rosbags.typesys import Stores, get_typestore

from sclam_ros.io.messages import MessageRejected, joint_state_to_raw, laser_scan_to_scan, stamp_to_sec
from sclam_ros.core.params import SclamParams

TS = get_typestore(Stores.ROS2_JAZZY)
Time = TS.types["builtin_interfaces/msg/Time"]
Header = TS.types["std_msgs/msg/Header"]
JointStateBag = TS.types["sensor_msgs/msg/JointState"]
LaserScanBag = TS.types["sensor_msgs/msg/LaserScan"]
PARAMS = SclamParams()


def bag_joint_state(sec, nanosec, names, positions):
    return JointStateBag(
        header=Header(stamp=Time(sec=sec, nanosec=nanosec), frame_id=""),
        name=list(names),
        position=np.asarray(positions, dtype=np.float64),
        velocity=np.zeros(0),
        effort=np.zeros(0),
    )


def test_stamp_to_sec_keeps_nanoseconds_for_epoch_stamps():
    t = stamp_to_sec(Time(sec=1_700_000_000, nanosec=123_456_789))
    assert t == pytest.approx(1_700_000_000.123456789, abs=1e-6)


def test_joint_state_picks_wheels_by_name_in_any_order():
    msg = bag_joint_state(12, 500_000_000, ["caster", "right_wheel_joint", "left_wheel_joint"], [9.0, 2.5, -1.5])
    assert joint_state_to_raw(msg, PARAMS) == (12.5, -1.5, 2.5)


def test_missing_joint_reason_lists_names_present():
    msg = bag_joint_state(1, 0, ["wheel_l", "wheel_r"], [0.0, 0.0])
    with pytest.raises(MessageRejected) as err:
        joint_state_to_raw(msg, PARAMS)
    assert err.value.reason == "joint_state_missing_joint"
    assert "wheel_l" in str(err.value) and "left_wheel_joint" in str(err.value)


def test_short_position_array_rejected():
    msg = bag_joint_state(1, 0, ["left_wheel_joint", "right_wheel_joint"], [0.0])
    with pytest.raises(MessageRejected) as err:
        joint_state_to_raw(msg, PARAMS)
    assert err.value.reason == "joint_state_short_position"


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_non_finite_position_rejected(bad):
    msg = bag_joint_state(1, 0, ["left_wheel_joint", "right_wheel_joint"], [0.0, bad])
    with pytest.raises(MessageRejected) as err:
        joint_state_to_raw(msg, PARAMS)
    assert err.value.reason == "joint_state_non_finite"


def test_laser_scan_keeps_geometry_and_all_ranges():
    ranges = np.array([1.0, 0.0, np.nan, np.inf, 50.0], dtype=np.float32)
    msg = LaserScanBag(
        header=Header(stamp=Time(sec=3, nanosec=250_000_000), frame_id="laser"),
        angle_min=1.0, angle_max=-1.0, angle_increment=-0.5, time_increment=1e-4,
        scan_time=0.1, range_min=0.1, range_max=10.0, ranges=ranges, intensities=np.zeros(0, np.float32),
    )
    scan = laser_scan_to_scan(msg)
    assert scan.stamp == 3.25 and scan.frame_id == "laser"
    assert scan.ranges.dtype == np.float64 and len(scan.ranges) == 5
    np.testing.assert_array_equal(np.isnan(scan.ranges), np.isnan(ranges))
    np.testing.assert_allclose(scan.angles(), [1.0, 0.5, 0.0, -0.5, -1.0])
    assert scan.angle_increment == -0.5 and scan.time_increment == pytest.approx(1e-4)


@pytest.mark.parametrize("angle_min, angle_max, increment, n, reason", [
    (np.nan, 1.0, 0.5, 5, "scan_non_finite_angles"),
    (-1.0, 1.0, np.inf, 5, "scan_non_finite_angles"),
    (-1.0, -1.0, 0.0, 5, "scan_zero_angle_increment"),
    (-1.0, 1.0, 0.5, 65, "scan_ranges_angles_mismatch"),  # 60 more ranges than described
    (-1.0, 1.0, -0.5, 5, "scan_ranges_angles_mismatch"),  # a mirrored scan
    (-1.0, 3999.0, 1000.0, 5, "scan_angles_span_over_a_turn"),  # beams wrap round
])
def test_laser_scan_with_impossible_geometry_is_rejected(angle_min, angle_max, increment, n, reason):
    msg = LaserScanBag(
        header=Header(stamp=Time(sec=3, nanosec=0), frame_id="laser"), angle_min=angle_min,
        angle_max=angle_max, angle_increment=increment, time_increment=0.0, scan_time=0.1,
        range_min=0.1, range_max=10.0, ranges=np.ones(n, np.float32),
        intensities=np.zeros(0, np.float32),
    )
    with pytest.raises(MessageRejected) as err:
        laser_scan_to_scan(msg)
    assert err.value.reason == reason


def test_rclpy_messages_are_accepted_by_duck_typing():
    """The same functions on real rclpy message classes (array.array fields, builtin Time)."""
    pytest.importorskip("rclpy")
    from sensor_msgs.msg import JointState, LaserScan

    js = JointState()
    js.header.stamp.sec, js.header.stamp.nanosec = 7, 250_000_000
    js.name = ["left_wheel_joint", "right_wheel_joint"]
    js.position = [100.0, -200.0]
    assert joint_state_to_raw(js, PARAMS) == (7.25, 100.0, -200.0)

    js.name = ["left_wheel_joint"]
    with pytest.raises(MessageRejected, match="left_wheel_joint"):
        joint_state_to_raw(js, PARAMS)

    ls = LaserScan()
    ls.header.stamp.sec, ls.header.frame_id = 4, "base_scan"
    ls.angle_min, ls.angle_max, ls.angle_increment = -0.5, 0.5, 0.25
    ls.range_min, ls.range_max = 0.1, 12.0
    ls.ranges = [1.0, float("inf"), 2.0, 0.0, 3.0]
    scan = laser_scan_to_scan(ls)
    assert scan.stamp == 4.0 and scan.frame_id == "base_scan"
    np.testing.assert_allclose(scan.ranges, [1.0, np.inf, 2.0, 0.0, 3.0])
    np.testing.assert_allclose(scan.angles(), [-0.5, -0.25, 0.0, 0.25, 0.5])
