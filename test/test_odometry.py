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
