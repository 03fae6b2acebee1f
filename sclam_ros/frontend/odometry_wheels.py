"""Wheel rotations implied from a base's wheel odometry (nav_msgs/Odometry), for robots that
publish no JointState of their wheels.

Each increment between two odometry poses is turned back into the two wheel rotations that
make it along the arc through both poses (core/kinematics.inverse), with the nominal radii
and wheel base the odometry was computed with; they are then calibrated as encoder angles
are. That holds for the odometry of a differential drive's wheels (diff_drive_controller, a
base driver). A base that fuses an IMU, a mouse sensor or a localisation into its odometry
has a heading that is not the wheels': the "wheel base" estimated from it is that of the
fused heading. Two signs of that are counted: increments that move sideways, and a twist
whose turning differs from the poses'.
"""
from __future__ import annotations

import math
from typing import Optional

import numpy as np

from sclam_ros.core import kinematics, se2
from sclam_ros.frontend.config import OdometryInputConfig


class WheelsFromOdometry:
    """Odometry poses in, cumulative (left, right) wheel angles (rad) out."""

    def __init__(self, params, config: Optional[OdometryInputConfig] = None):
        self.config = config or OdometryInputConfig()
        self.k = np.array([params.wheel_radius_left, params.wheel_radius_right,
                           params.wheel_base])
        # The encoder signs apply as to a JointState, so that the wiring check's advice
        # (left_encoder_sign: -1, ...) fixes this input too.
        self.signs = np.array([params.left_encoder_sign, params.right_encoder_sign])
        self.angles = np.zeros(2)
        self.increments = 0
        self.sideways = 0  # increments moving sideways by more than the tolerance
        self.sideways_total = 0.0  # m, Σ|sideways part| of those
        self.path = 0.0  # m, Σ|arc length|
        self.turning_poses = 0.0  # rad, Σ|dθ| of the poses
        self.turning_twist = 0.0  # rad, Σ|ω|·dt of the twist
        self._last: Optional[tuple] = None  # (stamp, pose)

    def add(self, stamp: float, pose, yaw_rate: float = 0.0) -> tuple:
        """(left, right): the wheel angles at this pose; ``yaw_rate`` (rad/s) is the
        message's twist, compared with the poses' turning."""
        pose = np.asarray(pose, float)
        if self._last is not None:
            last_stamp, last_pose = self._last
            motion = se2.between(pose, last_pose)
            dphi, across = kinematics.inverse(motion, self.k)
            self.angles = self.angles + dphi
            self.increments += 1
            if abs(across) > self.config.sideways_tolerance:
                self.sideways += 1
                self.sideways_total += abs(float(across))
            self.path += abs(float(kinematics.arc_length_and_rotation(dphi, self.k)[0]))
            self.turning_poses += abs(float(motion[2]))
            dt = stamp - last_stamp
            if 0.0 < dt < math.inf:
                self.turning_twist += abs(yaw_rate) * dt
        self._last = (stamp, pose)
        left, right = self.signs * self.angles
        return float(left), float(right)

    def twist_disagrees(self) -> bool:
        """The twist turns by another amount than the poses (twist_mismatch), over enough
        turning to tell; False when the twist is not filled in (all zero)."""
        if self.turning_poses < self.config.min_turning or self.turning_twist == 0.0:
            return False
        return abs(self.turning_twist / self.turning_poses - 1.0) > self.config.twist_mismatch
