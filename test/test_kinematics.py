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
