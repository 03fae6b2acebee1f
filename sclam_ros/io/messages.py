"""ROS messages → core input types, by duck typing.

The same functions take rclpy messages (``sensor_msgs.msg.JointState``, ``LaserScan``) and
messages deserialised by rosbags: both expose the same field names, so nothing here imports
rclpy or rosbags. Sequences may be Python lists, ``array.array`` (rclpy) or numpy arrays
(rosbags); ``np.asarray`` reads all three.

A message that cannot be used raises :class:`MessageRejected`; its ``reason`` is a short,
stable key meant for :class:`sclam_ros.core.inputs.Rejections`, its text says what was wrong.
"""
from __future__ import annotations

import math

import numpy as np

from sclam_ros.core.inputs import Scan


class MessageRejected(ValueError):
    """A message that is dropped on purpose. ``reason`` is the key to count it under."""

    def __init__(self, reason: str, detail: str):
        super().__init__(f"{reason}: {detail}")
        self.reason = reason
        self.detail = detail


def stamp_to_sec(stamp) -> float:
    """builtin_interfaces/Time (``sec``, ``nanosec``) → seconds as a float.

    A float64 keeps ~0.2 µs resolution for epoch stamps (1.7e9 s), far below any encoder
    or scan period, so the core works in plain seconds.
    """
    return float(stamp.sec) + 1e-9 * float(stamp.nanosec)


def joint_state_to_raw(msg, params) -> tuple[float, float, float]:
    """(stamp s, left position, right position) of the wheels of ``params``: of its two wheel
    joints, or for a skid-steer (``left_wheel_joints``, ``right_wheel_joints``) the mean of
    each side's (``side_position``).

    Positions stay in the encoder's raw unit (ticks, or radians when
    ``params.ticks_per_revolution`` is 0): unwrapping a counter needs the raw value, so the
    conversion to radians happens in :class:`sclam_ros.frontend.encoder_stream.EncoderStream`.
    Rejections: ``joint_state_wheels``.
    """
    stamp, left, right = joint_state_wheels(msg, params)
    return (stamp, side_position(left, params.encoder_wrap),
            side_position(right, params.encoder_wrap))


def joint_state_wheels(msg, params) -> tuple[float, np.ndarray, np.ndarray]:
    """(stamp s, left positions, right positions): the raw position of each wheel joint of
    ``params`` (one per side, or a skid-steer's several, in the order named), multiplied by
    ``params.left_encoder_sign`` / ``right_encoder_sign`` (a backwards encoder; a side's
    wheels count the same way).

    Raises MessageRejected with reason
      ``joint_state_missing_joint``   a wheel joint is not in ``name`` (the text lists the names present),
      ``joint_state_short_position``  ``position`` has fewer entries than a wheel's index in ``name``,
      ``joint_state_non_finite``      a wheel position is NaN or ±inf.
    """
    names = list(msg.name)
    left_joints, right_joints = params.wheel_joints()
    wanted = left_joints + right_joints
    missing = [joint for joint in wanted if joint not in names]
    if missing:
        raise MessageRejected(
            "joint_state_missing_joint",
            f"joint(s) {missing} not in JointState; names present: {names}",
        )
    position = np.asarray(msg.position, dtype=float)
    index = [names.index(joint) for joint in wanted]
    if len(position) <= max(index):
        raise MessageRejected(
            "joint_state_short_position",
            f"{len(names)} names but {len(position)} positions",
        )
    values = position[index]
    if not np.all(np.isfinite(values)):
        raise MessageRejected(
            "joint_state_non_finite",
            "wheel positions " + ", ".join(f"{j}={v}" for j, v in zip(wanted, values)))
    n = len(left_joints)
    return (stamp_to_sec(msg.header.stamp), params.left_encoder_sign * values[:n],
            params.right_encoder_sign * values[n:])


def side_position(values, wrap: float = 0.0) -> float:
    """One side's position: the mean of its wheels' raw positions (the one wheel's as it is).

    A counter with modulus ``wrap`` (> 0) is averaged around the circle: each wheel's offset
    from the first is taken within ±wrap/2, so a counter that wraps before its neighbour's
    does not move the mean by half the modulus. The mean may then lie outside [0, wrap); the
    step between two means is still the side's motion modulo ``wrap``, which
    EncoderStream unwraps."""
    values = np.asarray(values, dtype=float)
    if len(values) == 1:
        return float(values[0])
    offsets = values - values[0]
    if wrap > 0:
        offsets = (offsets + 0.5 * wrap) % wrap - 0.5 * wrap
    return float(values[0] + offsets.mean())


def quaternion_yaw(q) -> float:
    """The yaw (rad) of a geometry_msgs/Quaternion: its rotation about z (ZYX Euler angles)."""
    return math.atan2(2 * (q.w * q.z + q.x * q.y), 1 - 2 * (q.y * q.y + q.z * q.z))


def odometry_to_pose(msg, params) -> tuple[float, tuple, float]:
    """(stamp s, planar pose (x, y, yaw), yaw rate rad/s) of a nav_msgs/Odometry.

    Raises MessageRejected with reason
      ``odometry_child_frame``  child_frame_id names another frame than ``params.base_frame``
                                (an empty one is taken as the base frame),
      ``odometry_non_finite``   the stamp, position or orientation is NaN or ±inf.
    """
    child = str(msg.child_frame_id).lstrip("/")
    if child and child != params.base_frame.lstrip("/"):
        raise MessageRejected(
            "odometry_child_frame",
            f"child_frame_id {child}, not base_frame {params.base_frame}")
    p = msg.pose.pose.position
    yaw = quaternion_yaw(msg.pose.pose.orientation)
    stamp = stamp_to_sec(msg.header.stamp)
    values = (stamp, float(p.x), float(p.y), yaw, float(msg.twist.twist.angular.z))
    if not all(math.isfinite(v) for v in values):
        raise MessageRejected("odometry_non_finite", f"stamp, x, y, yaw, ω = {values}")
    return stamp, values[1:4], values[4]


def laser_scan_to_scan(msg) -> Scan:
    """sensor_msgs/LaserScan → Scan. Beams are not filtered here: the scan matcher decides
    what a valid return is (0, NaN, inf, out of limits), in one place. The beam geometry is
    checked here, because only the message carries ``angle_max`` to check it against.

    Raises MessageRejected with reason
      ``scan_non_finite_angles``       an angle (min, max, increment) is NaN or ±inf,
      ``scan_zero_angle_increment``    ``angle_increment`` is 0 (every beam in one direction),
      ``scan_angles_span_over_a_turn`` the beams cover more than one turn (an absurd increment),
      ``scan_ranges_angles_mismatch``  ``len(ranges)`` differs from what
                                       ``angle_min``/``angle_max``/``angle_increment`` describe.
    A negative increment is legal (beam i points at angle_min + i·angle_increment).
    """
    ranges = np.asarray(msg.ranges, dtype=float)
    angle_min, increment = float(msg.angle_min), float(msg.angle_increment)
    check_scan_geometry(len(ranges), angle_min, float(msg.angle_max), increment)
    return Scan(
        stamp=stamp_to_sec(msg.header.stamp),
        ranges=ranges,
        angle_min=angle_min,
        angle_increment=increment,
        range_min=float(msg.range_min),
        range_max=float(msg.range_max),
        time_increment=float(msg.time_increment),
        frame_id=str(msg.header.frame_id),
    )


def check_scan(scan: Scan) -> None:
    """The input gate of every converted scan, live (ros/node.py) and from a bag
    (io/recording.py): raise MessageRejected if ``scan`` cannot be used at all, so that the
    same message is counted under the same reason either way.

    Reasons
      ``scan_empty``             no ranges at all (a scan whose beams are all invalid passes:
                                 the scan matcher counts it),
      ``scan_non_finite_stamp``  the stamp is NaN or ±inf.
    """
    if len(scan.ranges) == 0:
        raise MessageRejected("scan_empty", "LaserScan without ranges")
    if not math.isfinite(scan.stamp):
        raise MessageRejected("scan_non_finite_stamp", "LaserScan stamp is not finite")


# Drivers disagree on whether angle_max is the last beam's angle or one increment beyond it
# (and float32 angles round): one beam either way is a convention, more is a wrong message.
BEAM_COUNT_TOLERANCE = 1


def check_scan_geometry(n: int, angle_min: float, angle_max: float, increment: float) -> None:
    """Raise MessageRejected if n beams from angle_min in steps of increment cannot be the
    scan that angle_max describes. An empty or one-beam scan has no geometry to contradict:
    it passes, and the scan matcher counts it as empty or too small."""
    if not (math.isfinite(angle_min) and math.isfinite(angle_max) and math.isfinite(increment)):
        raise MessageRejected(
            "scan_non_finite_angles",
            f"angle_min={angle_min}, angle_max={angle_max}, angle_increment={increment}")
    if n <= 1:
        return
    if increment == 0.0:
        raise MessageRejected("scan_zero_angle_increment", f"{n} beams all at {angle_min} rad")
    described = (angle_max - angle_min) / increment + 1.0
    if abs(n - described) > BEAM_COUNT_TOLERANCE + 0.01:  # + float32 rounding of the angles
        raise MessageRejected(
            "scan_ranges_angles_mismatch",
            f"{n} ranges, but angle_min={angle_min:.6g}, angle_max={angle_max:.6g}, "
            f"angle_increment={increment:.6g} describe {described:.1f} beams")
    # Beams may close the circle (the last one a step short of, or at, the first) but not wrap
    # around it: beyond that, different beams land on the same bearing and points collapse.
    if abs(increment) * (n - 1) > 2.0 * math.pi + abs(increment):
        raise MessageRejected(
            "scan_angles_span_over_a_turn",
            f"{n} beams × {increment} rad span {abs(increment) * (n - 1):.3g} rad")
