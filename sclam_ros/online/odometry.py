"""Corrected odometry: encoder samples integrated with the current calibration and its σ.

What the node publishes on ``~/odom``; kept free of rclpy so it is tested without DDS.
"""
from __future__ import annotations

import math

import numpy as np

from sclam_ros.core import kinematics
from sclam_ros.core.inputs import Rejections
from sclam_ros.frontend.encoder_stream import EncoderStream


class OdometryIntegrator:
    """Encoder samples → pose in the odom frame, with covariance.

    Uses its own :class:`EncoderStream` (unwrap, ticks → rad, segments at gaps and clock
    jumps) so that an increment across a break is never integrated. The covariance is the
    wheel noise (and the path's uncertainty between samples) accumulated step by step plus
    A Σ_k Aᵀ, where A = ∂pose/∂k is carried along the path: the calibration error is the
    same at every step, so it is propagated through the whole path, not added as if
    independent per step.

    A refused sample is counted in ``rejections`` under its ``encoder_*`` reason.
    """

    def __init__(self, params, rejections=None):
        self.params = params
        self.stream = EncoderStream.from_params(
            params, rejections=rejections if rejections is not None else Rejections())
        self.pose = np.zeros(3)
        self.noise_cov = np.zeros((3, 3))
        self.d_pose_d_k = np.zeros((3, 3))
        self.twist = np.zeros(3)  # (v_x, v_y, ω) in the base frame
        self.twist_cov = np.zeros((3, 3))
        self._last = None  # WheelAngles of the last kept sample

    def add(self, stamp, left_raw, right_raw, k, k_cov) -> bool:
        """Integrate one sample with calibration k (3,) of covariance k_cov (3, 3); False
        if the encoder stream refused it. A segment's first sample (the very first, or the
        first after a gap) moves nothing and has zero twist: no speed is known across it."""
        if not self.stream.add(stamp, left_raw, right_raw):
            return False
        angles = self.stream.wheel_angles_at(stamp)
        last, self._last = self._last, angles
        if angles is None or last is None or last.segment != angles.segment:
            self.twist = np.zeros(3)
            self.twist_cov = np.zeros((3, 3))
            return True
        # Between slow encoder samples the path may run beside the constant-speed arc
        # (EncoderStream._path_variance): without it the ~/odom covariance at 1-2 Hz
        # encoders is that of a path known exactly between samples.
        motion, j_k, m_cov = kinematics.step(
            angles.angles - last.angles, k, self.params.wheel_noise,
            lateral_noise=self.params.lateral_noise,
            path_variance=max(angles.path_variance - last.path_variance, 0.0),
        )
        c, s = math.cos(self.pose[2]), math.sin(self.pose[2])
        rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        j_pose = np.eye(3)
        j_pose[0, 2] = -s * motion[0] - c * motion[1]
        j_pose[1, 2] = c * motion[0] - s * motion[1]
        self.noise_cov = j_pose @ self.noise_cov @ j_pose.T + rot @ m_cov @ rot.T
        self.d_pose_d_k = j_pose @ self.d_pose_d_k + rot @ j_k
        self.pose = self.pose + rot @ motion
        self.pose[2] = math.atan2(math.sin(self.pose[2]), math.cos(self.pose[2]))
        dt = stamp - last.stamp
        if dt > 0:
            self.twist = motion / dt
            self.twist_cov = m_cov / dt**2
        return True

    def covariance(self, k_cov) -> np.ndarray:
        return self.noise_cov + self.d_pose_d_k @ k_cov @ self.d_pose_d_k.T
