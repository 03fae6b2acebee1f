"""marginal.py: Gaussians left by marginalised keyframes, the prior factor they become, and
the radius-change test, checked against linear-Gaussian algebra done by hand."""
import numpy as np
import pytest

from numdiff import check_factor_jacobians
from sclam_ros.core.marginal import (
    CalibrationPriorFactor,
    Gaussian,
    gaussian_of_prior,
    radius_change_statistic,
)
from sclam_ros.core.solver import Values

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


def _posterior(prior: Gaussian, window: Gaussian):
    total = prior + window
    cov = np.linalg.inv(total.information)
    return cov @ total.eta, cov


def test_change_statistic_is_chi2_without_a_change_and_large_with_one():
    """Prior from old data, window from new data of the same radii: the statistic is χ²(2)
    distributed (mean 2); with the left radius 1 % smaller in the window, it is large."""
    rng = np.random.default_rng(2)
    prior_cov = np.diag([1e-4, 1e-4, 1e-3, 1e-3, 1e-3, 1e-3]) ** 2
    window_cov = 4 * prior_cov
    prior_info, window_info = np.linalg.inv(prior_cov), np.linalg.inv(window_cov)
    stats_same, stats_changed = [], []
    for _ in range(2000):
        old = TRUE + rng.multivariate_normal(np.zeros(6), prior_cov)
        new = TRUE + rng.multivariate_normal(np.zeros(6), window_cov)
        prior = Gaussian(prior_info, prior_info @ old)
        for shift, out in ((0.0, stats_same), (-0.01 * TRUE[0], stats_changed)):
            observed = new + np.array([shift, 0, 0, 0, 0, 0])
            mean, cov = _posterior(prior, Gaussian(window_info, window_info @ observed))
            out.append(radius_change_statistic(prior, mean, cov))
    assert np.mean(stats_same) == pytest.approx(2.0, rel=0.1)
    assert np.mean(np.array(stats_same) > 9.21) < 0.02  # p = 0.01 quantile of χ²(2)
    # 1 % of 0.1 m over σ √(2e-4² + 1e-4²) of the difference: (1e-3)² / 5e-8 = 20.
    assert np.median(stats_changed) > 15


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
