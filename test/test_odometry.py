"""online/odometry.py: the ~/odom integrator, without a ROS graph."""
import numpy as np

from sclam_ros.core.params import SclamParams
from sclam_ros.online.odometry import OdometryIntegrator


def test_odometry_integrator_drives_straight_and_turns_in_place():
    params = SclamParams(ticks_per_revolution=1000.0, wheel_radius_left=0.1,
                         wheel_radius_right=0.1, wheel_base=0.5)
    odo = OdometryIntegrator(params)
    k, k_cov = np.array([0.1, 0.1, 0.5]), np.diag([1e-6, 1e-6, 1e-4])
    for i in range(11):  # one revolution of both wheels in 10 steps
        odo.add(0.1 * i, 100.0 * i, 100.0 * i, k, k_cov)
    np.testing.assert_allclose(odo.pose, [2 * np.pi * 0.1, 0, 0], atol=1e-12)
    cov = odo.covariance(k_cov)
    assert np.all(np.linalg.eigvalsh(cov) > 0)
    # The radius uncertainty, shared by every step, adds to the wheel noise.
    assert cov[0, 0] > odo.noise_cov[0, 0]
    for i in range(11, 21):  # opposite wheels: turn in place
        odo.add(0.1 * i, 1000.0 - 100.0 * (i - 10), 100.0 * i, k, k_cov)
    assert abs(odo.pose[0] - 2 * np.pi * 0.1) < 1e-9
    # A sample going back in time is refused and integrates nothing.
    pose = odo.pose.copy()
    assert not odo.add(1.0, 0.0, 0.0, k, k_cov)
    np.testing.assert_array_equal(odo.pose, pose)


def test_odometry_covariance_covers_the_path_between_slow_encoder_samples():
    """At 2 Hz the path between samples is not the constant-speed arc the integrator
    assumes: a robot turning harder, then straightening, ends up millimetres beside it.
    The covariance must cover that (EncoderStream's path variance), not only the wheel
    noise. The truth is the same wheels sampled at 1 kHz."""
    params = SclamParams(ticks_per_revolution=10000.0, wheel_radius_left=0.1,
                         wheel_radius_right=0.1, wheel_base=0.5, wheel_noise=1e-4,
                         lateral_noise=1e-4)
    k, k_cov = np.array([0.1, 0.1, 0.5]), np.zeros((3, 3))
    t = np.arange(0.0, 6.0 + 1e-9, 0.001)
    # Left wheel at 2 rad/s; the right one speeds up to 6 rad/s over 3 s and back.
    right_speed = np.where(t < 3.0, 2.0 + 4.0 * t / 3.0, 6.0 - 4.0 * (t - 3.0) / 3.0)
    right = np.concatenate([[0.0], np.cumsum(0.5 * (right_speed[1:] + right_speed[:-1]) * 0.001)])
    ticks_per_rad = 10000.0 / (2.0 * np.pi)

    def integrate(step):
        odo = OdometryIntegrator(params)
        for i in range(0, len(t), step):
            odo.add(t[i], 2.0 * t[i] * ticks_per_rad, right[i] * ticks_per_rad, k, k_cov)
        return odo

    truth = integrate(1).pose
    slow = integrate(500)
    error = slow.pose - truth
    cov = slow.covariance(k_cov)[:2, :2]
    assert np.hypot(*error[:2]) > 0.002  # the effect is there: millimetres
    assert np.sqrt(error[:2] @ np.linalg.solve(cov, error[:2])) < 4.0
