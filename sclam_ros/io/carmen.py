"""CARMEN logs (the Radish / Freiburg SLAM benchmark's ``.clf``) to rosbag2.

A CARMEN log is one message per line, ``NAME [contents] ipc_timestamp ipc_hostname
logger_timestamp``. Read here:

    ODOM x y theta tv rv accel
    FLASER n r_1..r_n x y theta odom_x odom_y odom_theta
    ROBOTLASER1 type start_angle fov resolution max_range accuracy remission_mode
                n r_1..r_n m e_1..e_m laser_x laser_y laser_theta robot_x robot_y robot_theta
                tv rv forward_safety side_safety turn_axis
    PARAM name value

The logs carry the robot's own integrated odometry pose, not its wheels: each pose increment
is turned back into the two wheel rotations that a differential drive with the stated
nominal radius and wheel base would need to make it (along the arc through both poses).
The calibration is then relative to those nominal values: a calibrated radius of 0.95 ×
nominal means the logged odometry over-reads distance by 5 %. The sideways part of an
increment (zero for a differential drive's own odometry) has no wheel rotation and is
dropped; its size is reported.

Where the log has no ODOM lines, the odometry pose logged inside each laser line is used.
The laser's mount comes from the laser lines (laser pose against robot pose), else from the
``robot_frontlaser_offset`` PARAM (metres ahead of the robot's centre), else 0.

FLASER beams: n beams spanning 180° from −90° to +90° inclusive, π/(n − 1) apart, as the
logtools of the benchmark's authors read them (``carmen_parse_line``); ROBOTLASER1 states its
own geometry. The spacing matters: read 1° apart instead, the 180 beams of the ACES log
span 179°, and the scan matches' rotations come out 1.5 % too large against the benchmark's
relations (docs/real_data.md).
The maximal range marks "no return" and becomes +inf (REP-117).
"""
from __future__ import annotations

import bz2
import gzip
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from sclam_ros.core import kinematics, se2
from sclam_ros.core.inputs import Scan
from sclam_ros.core.params import SclamParams
from sclam_ros.io.bag import BagWriter

# The nominal differential drive the wheel rotations are implied with: any value works
# (the calibration is relative to it); these are a Pioneer-class base's.
NOMINAL_RADIUS = 0.1  # m
NOMINAL_BASE = 0.4  # m
JOINTS = ("left_wheel_joint", "right_wheel_joint")
FLASER_MAX_RANGE = 50.0  # m: the SICK LMS in the benchmark logs reports no return as 50 m
# rad, −90° to +90° inclusive: a FLASER line states no field of view, and CARMEN's own
# reader spreads its beams over this; a laser that spans less makes its scan matches turn
# by more than it does (sclam convert carmen --fov, docs/real_data.md)
FLASER_FOV = math.pi
NO_RETURN_MARGIN = 0.01  # m: a reading within this of the maximum is "no return"


class CarmenError(ValueError):
    """A log that cannot be read as CARMEN; the message names the line."""


@dataclass
class LaserLine:
    stamp: float  # s, ipc_timestamp
    ranges: np.ndarray  # m
    angle_min: float  # rad
    angle_increment: float  # rad
    range_max: float  # m
    laser_pose: np.ndarray  # (x, y, θ) in the odometry frame
    robot_pose: np.ndarray  # (x, y, θ) odometry pose at the scan


@dataclass
class CarmenLog:
    odometry_stamps: list = field(default_factory=list)  # s
    odometry_poses: list = field(default_factory=list)  # (x, y, θ)
    lasers: list = field(default_factory=list)  # LaserLine
    params: dict = field(default_factory=dict)  # PARAM name → value text
    skipped: dict = field(default_factory=dict)  # message name → count of lines not read


def _open_text(path: Path):
    if path.suffix == ".bz2":
        return bz2.open(path, "rt", errors="replace")
    if path.suffix == ".gz":
        return gzip.open(path, "rt", errors="replace")
    return open(path, "rt", errors="replace")


def _floats(tokens, where):
    try:
        return [float(t) for t in tokens]
    except ValueError:
        raise CarmenError(f"{where}: a number was expected in {' '.join(tokens)[:80]!r}") from None


def _flaser(tokens, where, fov) -> LaserLine:
    n = int(tokens[1])
    values = _floats(tokens[2:2 + n + 6], where)
    if len(values) != n + 6 or len(tokens) < 2 + n + 7:
        raise CarmenError(f"{where}: FLASER line shorter than its {n} readings say")
    return LaserLine(
        stamp=float(tokens[2 + n + 6]), ranges=np.asarray(values[:n]),
        angle_min=-fov / 2, angle_increment=fov / max(n - 1, 1),
        range_max=FLASER_MAX_RANGE,
        laser_pose=np.asarray(values[n:n + 3]), robot_pose=np.asarray(values[n + 3:n + 6]))


def _robotlaser(tokens, where) -> LaserLine:
    start, _fov, resolution, max_range = _floats(tokens[2:6], where)
    n = int(tokens[8])
    ranges = _floats(tokens[9:9 + n], where)
    m = int(tokens[9 + n])
    at = 10 + n + m
    poses = _floats(tokens[at:at + 6], where)
    if len(poses) != 6 or len(tokens) < at + 12:
        raise CarmenError(f"{where}: ROBOTLASER1 line shorter than its readings say")
    return LaserLine(
        stamp=float(tokens[at + 11]), ranges=np.asarray(ranges), angle_min=start,
        angle_increment=resolution, range_max=max_range,
        laser_pose=np.asarray(poses[:3]), robot_pose=np.asarray(poses[3:]))


def read_carmen(path, flaser_fov: float = FLASER_FOV) -> CarmenLog:
    """Parse the lines this converter uses; others are counted in ``skipped``.
    flaser_fov (rad): the span of an FLASER line's beams, first to last."""
    path = Path(path)
    log = CarmenLog()
    try:
        handle = _open_text(path)
        with handle:
            for number, line in enumerate(handle, 1):
                tokens = line.split()
                if not tokens or tokens[0].startswith("#"):
                    continue
                where = f"{path.name}:{number}"
                name = tokens[0]
                try:
                    if name == "ODOM":
                        values = _floats(tokens[1:4] + tokens[7:8], where)
                        log.odometry_poses.append(values[:3])
                        log.odometry_stamps.append(values[3])
                    elif name == "FLASER":
                        log.lasers.append(_flaser(tokens, where, flaser_fov))
                    elif name == "ROBOTLASER1":
                        log.lasers.append(_robotlaser(tokens, where))
                    elif name == "PARAM" and len(tokens) >= 3:
                        log.params[tokens[1]] = tokens[2]
                    else:
                        log.skipped[name] = log.skipped.get(name, 0) + 1
                except (IndexError, ValueError) as exc:
                    if isinstance(exc, CarmenError):
                        raise
                    raise CarmenError(f"{where}: malformed {name} line ({exc})") from None
    except OSError as exc:
        raise CarmenError(f"{path}: cannot read: {exc}") from None
    if not log.lasers:
        raise CarmenError(f"{path}: no FLASER or ROBOTLASER1 lines: not a CARMEN laser log")
    return log


def implied_wheel_angles(poses: np.ndarray, radius: float, base: float):
    """Cumulative (left, right) wheel angles (rad) that reproduce each pose increment along
    the arc through both poses (core/kinematics.inverse), and the sideways part of each
    increment (m) they cannot."""
    poses = np.asarray(poses, dtype=float)
    dphi, across = kinematics.inverse(se2.between(poses[1:], poses[:-1]),
                                      (radius, radius, base))
    angles = np.zeros((len(poses), 2))
    angles[1:] = np.cumsum(dphi, axis=0)
    return angles, across


def laser_mount(log: CarmenLog) -> np.ndarray:
    """(x, y, yaw) of the laser on the robot: the median of the laser lines' laser pose in
    their robot pose, else the front-laser PARAM, else zero."""
    rel = []
    for laser in log.lasers:
        rx, ry, rth = laser.robot_pose
        dx, dy = laser.laser_pose[0] - rx, laser.laser_pose[1] - ry
        c, s = math.cos(rth), math.sin(rth)
        rel.append((c * dx + s * dy, -s * dx + c * dy,
                    math.remainder(laser.laser_pose[2] - rth, 2 * math.pi)))
    mount = np.median(np.asarray(rel), axis=0)
    if np.allclose(mount, 0.0, atol=1e-6) and "robot_frontlaser_offset" in log.params:
        mount = np.array([float(log.params["robot_frontlaser_offset"]), 0.0, 0.0])
    return mount


def odometry_track(log: CarmenLog):
    """(stamps, poses, source): the ODOM lines, else the odometry poses in the laser lines."""
    if log.odometry_stamps:
        return np.asarray(log.odometry_stamps), np.asarray(log.odometry_poses), "ODOM lines"
    stamps = np.asarray([laser.stamp for laser in log.lasers])
    poses = np.asarray([laser.robot_pose for laser in log.lasers])
    return stamps, poses, "the odometry poses inside the laser lines"


def carmen_params(mount, radius=NOMINAL_RADIUS, base=NOMINAL_BASE) -> SclamParams:
    return SclamParams(
        ticks_per_revolution=0.0, wheel_radius_left=radius, wheel_radius_right=radius,
        wheel_base=base, laser_x=float(mount[0]), laser_y=float(mount[1]),
        laser_yaw=float(mount[2]),
    ).validate()


def laser_scan(laser: LaserLine, delay: float = 0.0) -> Scan:
    """The scan of a laser line, stamped ``delay`` s before the line's ipc_timestamp."""
    ranges = np.array(laser.ranges, dtype=float)
    ranges[ranges >= laser.range_max - NO_RETURN_MARGIN] = np.inf
    return Scan(stamp=laser.stamp - delay, ranges=ranges, angle_min=laser.angle_min,
                angle_increment=laser.angle_increment, range_min=0.0,
                range_max=laser.range_max, time_increment=0.0, frame_id="laser")
