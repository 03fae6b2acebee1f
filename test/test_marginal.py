"""marginal.py: Gaussians left by marginalised keyframes and the prior factor they become,
checked against linear-Gaussian algebra done by hand."""
import numpy as np
import pytest

from numdiff import check_factor_jacobians
from sclam_ros.core.marginal import (
    CalibrationPriorFactor,
    Gaussian,
    gaussian_of_prior,
)
from sclam_ros.core.problem import Values

TRUE = np.array([0.1, 0.101, 0.4, 0.2, -0.05, 0.1])


def _random_gaussian(rng, mean, scale=1e4):
    a = rng.standard_normal((6, 6))
    information = scale * (a @ a.T + 6 * np.eye(6))
    return Gaussian(information, information @ mean)


def test_without_radii_is_the_marginal_of_the_covariance():
    rng = np.random.default_rng(0)
    g = _random_gaussian(rng, TRUE)
    marginal = g.without_radii()
    cov = np.linalg.inv(g.information)
    # Marginalising in information form = taking the sub-block of the covariance.
    np.testing.assert_allclose(np.linalg.inv(marginal.information[2:, 2:]), cov[2:, 2:], rtol=1e-8)
    np.testing.assert_allclose(np.linalg.solve(marginal.information[2:, 2:], marginal.eta[2:]),
                               TRUE[2:], atol=1e-10)
    assert not np.any(marginal.information[:2]) and not np.any(marginal.eta[:2])


def test_mean_of_a_gaussian_without_radii_information():
    rng = np.random.default_rng(1)
    g = _random_gaussian(rng, TRUE).without_radii()
    np.testing.assert_allclose(g.mean()[2:], TRUE[2:], atol=1e-10)


def test_prior_factor_residual_and_jacobians():
    rng = np.random.default_rng(3)
    g = _random_gaussian(rng, TRUE)
    factor = CalibrationPriorFactor(g)
    values = Values({"poses": np.zeros((1, 3)), "odometry": [TRUE[:3] + 1e-3],
                     "laser": [TRUE[3:] - 1e-3]},
                    angular={"poses": [False, False, True], "laser": [False, False, True]})
    lin = factor.linearize(values)
    whitened = lin.sqrt_information[0] @ lin.residual[0]
    delta = np.concatenate([np.full(3, 1e-3), np.full(3, -1e-3)])
    assert whitened @ whitened == pytest.approx(delta @ g.information @ delta, rel=1e-9)
    check_factor_jacobians(factor, values)


def test_gaussian_of_prior():
    g = gaussian_of_prior(TRUE, np.full(6, 0.5))
    np.testing.assert_allclose(g.mean(), TRUE)
    np.testing.assert_allclose(g.information, 4 * np.eye(6))
