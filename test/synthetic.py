"""Synthetic calibration graphs drawn from the generative model itself (no scans, no ICP).

Used to test the solver in isolation: with exactly known noise, the estimate must land
within its reported σ of the truth.
"""
import numpy as np

from sclam_ros.core import kinematics, se2


def wheel_increments(n, rng, speed=0.4, dt=0.1, radius=0.125, base=0.56):
    """A smooth mix of straight runs and left/right turns, as wheel angle increments."""
    t = np.arange(n) * dt
    v = speed * (0.6 + 0.4 * np.sin(0.05 * t))
    w = 0.8 * np.sin(0.21 * t) * np.sign(np.sin(0.03 * t + 0.3))
    right = (v + w * base / 2) * dt / radius
    left = (v - w * base / 2) * dt / radius
    return np.column_stack([left, right])


def make_graph(n=600, k_true=(0.1263, 0.1275, 0.5825), l_true=(0.2258, 0.0026, 0.0017),
               wheel_noise=0.01, laser_sigma=(0.002, 0.002, 0.001), seed=0):
    rng = np.random.default_rng(seed)
    k_true, l_true = np.array(k_true), np.array(l_true)
    dphi_true = wheel_increments(n - 1, rng)
    poses = np.zeros((n, 3))
    for i, d in enumerate(dphi_true):
        poses[i + 1] = se2.compose(poses[i], kinematics.forward(d, k_true))
    # Encoders measure the wheel angles with slip noise ∝ sqrt(|angle|).
    dphi_meas = dphi_true + rng.normal(size=dphi_true.shape) * wheel_noise * np.sqrt(np.abs(dphi_true))
    laser_poses = se2.compose(poses, l_true)
    z_true = se2.between(laser_poses[1:], laser_poses[:-1])
    z_meas = z_true + rng.normal(size=z_true.shape) * np.array(laser_sigma)
    return dict(poses=poses, dphi=dphi_meas, z=z_meas, k=k_true, l=l_true,
                wheel_noise=wheel_noise, laser_sigma=np.array(laser_sigma))
