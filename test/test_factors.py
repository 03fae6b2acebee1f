import numpy as np
from numdiff import central_difference, check_factor_jacobians

from sclam_ros.core import factors, kinematics, se2
from sclam_ros.core.problem import Values

rng = np.random.default_rng(3)


def random_values(n=6):
    poses = np.column_stack([rng.normal(0, 3, (n, 2)), rng.uniform(-3, 3, n)])
    return Values(
        {"poses": poses, "odometry": [[0.12, 0.13, 0.55]], "laser": [[0.22, -0.05, 0.4]]},
        angular={"poses": [False, False, True], "laser": [False, False, True]},
    )


def test_odometry_factor_jacobians():
    values = random_values()
    dphi = rng.normal(0, 2, (5, 2))
    f = factors.OdometryFactor(np.arange(5), np.arange(1, 6), dphi, np.tile(np.eye(3), (5, 1, 1)))
    check_factor_jacobians(f, values)


def test_laser_factor_jacobians():
    values = random_values()
    z = np.column_stack([rng.normal(0, 1, (5, 2)), rng.uniform(-1, 1, 5)])
    f = factors.LaserFactor(np.arange(5), np.arange(1, 6), z, np.tile(np.eye(3), (5, 1, 1)))
    check_factor_jacobians(f, values)


def test_prior_factor_jacobians():
    values = random_values()
    f = factors.PriorFactor("laser", [0], [[0.2, 0.0, 3.1]], np.eye(3))
    check_factor_jacobians(f, values)


def test_residuals_vanish_at_truth():
    values = random_values(2)
    k, l = values["odometry"][0], values["laser"][0]
    dphi = np.array([[1.0, 1.4]])
    values["poses"][1] = se2.compose(values["poses"][0], kinematics.forward(dphi[0], k))
    odo = factors.OdometryFactor([0], [1], dphi, np.eye(3)[None])
    assert np.allclose(odo.residuals(values), 0, atol=1e-12)
    laser_motion = se2.between(
        se2.compose(values["poses"][1], l), se2.compose(values["poses"][0], l)
    )
    las = factors.LaserFactor([0], [1], laser_motion[None], np.eye(3)[None])
    assert np.allclose(las.residuals(values), 0, atol=1e-12)


def test_sqrt_information_reconstructs_information():
    a = rng.normal(size=(4, 3, 3))
    info = a @ np.swapaxes(a, -1, -2) + 0.1 * np.eye(3)
    root = factors.sqrt_information(info)
    assert np.allclose(np.swapaxes(root, -1, -2) @ root, info)



def test_odometry_factor_with_sub_interval_parts_jacobians():
    values = random_values()
    parts = rng.normal(0.5, 0.4, (5, 4, 2))
    parts[2, 3] = 0.0  # padding
    f = factors.OdometryFactor(np.arange(5), np.arange(1, 6), parts.sum(1),
                               np.tile(np.eye(3), (5, 1, 1)), parts=parts)
    check_factor_jacobians(f, values)
