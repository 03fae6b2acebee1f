import numpy as np
import pytest
from numdiff import central_difference

from sclam_ros.core import kinematics, se2

K = np.array([0.1263, 0.1275, 0.5825])


def integrate_finely(dphi, k, steps=20000):
    """Reference: compose many tiny straight steps (Euler), converging to the exact arc."""
    pose = np.zeros(3)
    small = np.asarray(dphi) / steps
    s, th = kinematics.arc_length_and_rotation(small, k)
    for _ in range(steps):
        pose = se2.compose(pose, np.array([s * np.cos(th / 2), s * np.sin(th / 2), th]))
    return pose


@pytest.mark.parametrize("dphi", [(1.0, 1.0), (0.5, 2.0), (-1.0, 1.0), (3.0, -0.2), (1e-5, 1.2e-5)])
def test_forward_matches_fine_integration(dphi):
    assert np.allclose(kinematics.forward(np.array(dphi), K), integrate_finely(dphi, K), atol=1e-8)


def test_straight_line_and_pure_rotation():
    straight = kinematics.forward(np.array([2.0, 2.0]), np.array([0.1, 0.1, 0.5]))
    assert np.allclose(straight, [0.2, 0.0, 0.0])
    spin = kinematics.forward(np.array([-1.0, 1.0]), np.array([0.1, 0.1, 0.5]))
    assert np.allclose(spin, [0.0, 0.0, 0.4])


def test_small_angle_branch_is_continuous():
    k = np.array([0.1, 0.1, 0.5])
    # Straddle the switch between series and closed form.
    below = kinematics.forward(np.array([1.0, 1.0 + 2.4e-3]), k)
    above = kinematics.forward(np.array([1.0, 1.0 + 2.6e-3]), k)
    mid = kinematics.forward(np.array([1.0, 1.0 + 2.5e-3]), k)
    assert np.allclose(mid, 0.5 * (below + above), atol=1e-9)


@pytest.mark.parametrize("dphi", [(1.0, 1.3), (0.2, -0.7), (1.0, 1.0), (1.0, 1.0 + 1e-6), (-2.0, 3.0)])
def test_jacobian_k_matches_central_differences(dphi):
    dphi = np.array(dphi)
    numeric = central_difference(lambda k: kinematics.forward(dphi, k), K)
    assert np.allclose(kinematics.jacobian_k(dphi, K), numeric, atol=1e-7)


@pytest.mark.parametrize("dphi", [(1.0, 1.3), (0.2, -0.7), (1.0, 1.0)])
def test_jacobian_u_matches_central_differences(dphi):
    dphi = np.array(dphi)
    numeric = central_difference(lambda u: kinematics.forward(u, K), dphi)
    assert np.allclose(kinematics.jacobian_u(dphi, K), numeric, atol=1e-7)


def test_vectorised_equals_single():
    dphi = np.random.default_rng(0).normal(0, 1, (7, 2))
    stacked = kinematics.jacobian_k(dphi, K)
    for i in range(7):
        assert np.allclose(stacked[i], kinematics.jacobian_k(dphi[i], K))


@pytest.mark.parametrize("dphi", [(1.0, 1.0), (0.5, 2.0), (-1.0, 1.0), (3.0, -0.2),
                                  (1e-5, 1.2e-5), (0.0, 0.0)])
def test_step_is_forward_jacobian_and_covariance_of_one_increment(dphi):
    motion, j_k, cov = kinematics.step(dphi, K, 0.02, lateral_noise=0.01, path_variance=1e-6)
    np.testing.assert_allclose(motion, kinematics.forward(dphi, K), rtol=1e-14, atol=1e-17)
    np.testing.assert_allclose(j_k, kinematics.jacobian_k(dphi, K), rtol=1e-14, atol=1e-17)
    expected = kinematics.motion_covariance(dphi, K, 0.02, lateral_noise=0.01, path_variance=1e-6)
    np.testing.assert_allclose(cov, expected, rtol=1e-12, atol=1e-30)


def test_motion_covariance_positive_definite_even_standing_still():
    cov = kinematics.motion_covariance(np.array([[0.0, 0.0], [1.0, 1.2]]), K, 0.02)
    assert np.all(np.linalg.eigvalsh(cov) > 0)


def test_composed_arcs_match_fine_integration_and_jacobian():
    from numdiff import central_difference

    parts = np.array([[1.0, 1.4], [1.2, 0.6], [0.0, 0.0], [0.9, 1.0]])  # an S-curve, padded
    motion, jac = kinematics.forward_composed(parts, K)
    pose = np.zeros(3)
    for p in parts:
        pose = se2.compose(pose, integrate_finely(p, K, steps=2000))
    assert np.allclose(motion, pose, atol=1e-7)
    # Not the single arc of the summed increments: that assumes constant curvature.
    assert not np.allclose(motion, kinematics.forward(parts.sum(0), K), atol=1e-3)
    numeric = central_difference(lambda k: kinematics.forward_composed(parts, k)[0], K)
    assert np.allclose(jac, numeric, atol=1e-7)


def test_jacobian_u_composed_matches_central_differences():
    parts = np.array([[1.0, 1.4], [1.2, 0.6], [-0.8, 0.9], [0.0, 0.0]])  # padded
    jac = kinematics.jacobian_u_composed(parts, K)
    for p in range(len(parts)):
        def moved(u, p=p):
            shifted = parts.copy()
            shifted[p] = u
            return kinematics.forward_composed(shifted, K)[0]
        assert np.allclose(jac[p], central_difference(moved, parts[p]), atol=1e-7)


def _spin_with_slip(rng, draws, wheel_noise, n_parts=12):
    """A 0.6 rad turn on the spot in n_parts steps; each wheel slips by a random walk
    (variance wheel_noise²·|angle| per step). Returns the measured parts and the true motion
    of each draw (the wheels' true increments are the measured ones minus the slip)."""
    turn = 0.6
    wheel_angle = turn * K[2] / 2 / np.array([K[0], K[1]])  # rad per wheel for the whole turn
    measured = np.tile(np.array([-wheel_angle[0], wheel_angle[1]]) / n_parts, (n_parts, 1))
    slip = rng.standard_normal((draws, n_parts, 2)) * wheel_noise * np.sqrt(np.abs(measured))
    true_motion = kinematics.forward_composed(measured - slip, K)[0]
    return measured, true_motion


def test_motion_covariance_of_parts_is_that_of_the_slip_along_the_turn():
    """Physics: slip during a turn on the spot moves the robot along the arc's tangent as it
    turns. The covariance from the parts matches the spread of 4000 such turns in every
    direction, the single arc's does not: it has (almost) no variance across the chord."""
    rng = np.random.default_rng(5)
    wheel_noise = 0.02
    measured, true_motion = _spin_with_slip(rng, 4000, wheel_noise)
    model = kinematics.forward_composed(measured, K)[0]
    errors = true_motion - model
    errors[:, 2] = se2.wrap_angle(errors[:, 2])
    empirical = np.cov(errors.T)

    def whitened_variances(cov):
        root = np.linalg.cholesky(np.linalg.inv(cov))
        return np.linalg.eigvalsh(root.T @ empirical @ root)

    by_parts = kinematics.motion_covariance(measured.sum(0), K, wheel_noise, floor=1e-14,
                                            parts=measured)
    single_arc = kinematics.motion_covariance(measured.sum(0), K, wheel_noise, floor=1e-14)
    assert np.all(np.abs(whitened_variances(by_parts) - 1.0) < 0.1)
    assert whitened_variances(single_arc).max() > 10.0


def test_odometry_residual_is_whitened_by_the_motion_covariance():
    """The odometry factor compares motions in the edge's start frame, where the motion
    covariance is stated: at the true poses its whitened residuals of slipping turns on the
    spot have unit variance in every direction."""
    from sclam_ros.core import factors
    from sclam_ros.core.problem import Values

    rng = np.random.default_rng(6)
    wheel_noise = 0.02
    measured, true_motion = _spin_with_slip(rng, 2000, wheel_noise)
    start = np.array([1.0, -2.0, 2.5])
    poses = np.concatenate([np.tile(start, (len(true_motion), 1)), se2.compose(start, true_motion)])
    n = len(true_motion)
    cov = kinematics.motion_covariance(measured.sum(0), K, wheel_noise, floor=1e-14, parts=measured)
    f = factors.OdometryFactor(np.arange(n), np.arange(n) + n, np.tile(measured.sum(0), (n, 1)),
                               np.tile(np.linalg.inv(cov), (n, 1, 1)),
                               parts=np.tile(measured, (n, 1, 1)))
    values = Values({"poses": poses, "odometry": [K]}, angular={"poses": [False, False, True]})
    lin = f.linearize(values)
    whitened = np.einsum("nij,nj->ni", lin.sqrt_information, lin.residual)
    assert np.all(np.abs(np.linalg.eigvalsh(np.cov(whitened.T)) - 1.0) < 0.12)


def test_inverse_recovers_the_wheel_increments_and_measures_sideways_motion():
    rng = np.random.default_rng(5)
    k = np.array([0.098, 0.103, 0.41])
    # Straight, nearly straight (the series branch), turns, spins, reversing.
    dphi = np.concatenate([rng.normal(0, 2.0, (200, 2)), [[1.0, 1.0], [1.0, 1.0 + 1e-6],
                                                          [-2.0, 2.0], [-1.5, -1.5]]])
    got, across = kinematics.inverse(kinematics.forward(dphi, k), k)
    np.testing.assert_allclose(got, dphi, atol=1e-9)
    np.testing.assert_allclose(across, 0.0, atol=1e-12)
    # A sideways push perpendicular to the arc's chord is what `across` reports.
    motion = kinematics.forward(np.array([3.0, 4.0]), k)
    half = motion[2] / 2
    pushed = motion + 0.01 * np.array([-np.sin(half), np.cos(half), 0.0])
    got, across = kinematics.inverse(pushed, k)
    np.testing.assert_allclose(got, [3.0, 4.0], atol=1e-9)
    assert across == pytest.approx(0.01, abs=1e-12)
