"""A noise effect's likelihood ratio is that of its shape: zero where it finds no change.

The evidence (evidence.evaluate) takes a noise effect's likelihood ratio from
Models.fit_whole, as 2·ΔNLL of the laser-vs-odometry disagreements. Here the disagreements
are synthetic and their variance does not depend on the speed; the base model's level of
the wheels' noise (factor 1: the stated noise at its variance-component scale) is far
above what the disagreements show (exact encoders: the wheels' true share is 0), so every
free overall factor on the wheels' noise gains hundreds of nats. A noise effect must not
take that gain: at a variance ratio of one, its likelihood ratio is zero.
"""
import numpy as np
import pytest

from sclam_ros.diagnosis import disagreement as disagreement_mod
from sclam_ros.diagnosis.cross_validation import Models
from sclam_ros.diagnosis.disagreement import Disagreement
from sclam_ros.diagnosis.effects import EffectData
from sclam_ros.diagnosis.fitting import Edges, Fit

ODOMETRY_COV = np.diag([4e-6, 1e-6, 3e-5])  # the wheels' share at factor 1
LASER_COV = np.diag([1e-6, 1e-6, 2e-6])


def _models(monkeypatch, rng, m, wheel_factor):
    """Models over m edges of a drive at random speeds, whose disagreements have
    covariance wheel_factor·(wheels' share) + laser (wheel_factor (m,))."""
    stamps = np.arange(m + 1.0)
    speed = rng.uniform(0.1, 1.0, m + 1)
    positions = np.column_stack([np.cumsum(speed), np.zeros(m + 1)])  # 1 s per step
    data = EffectData(stamps, np.zeros((m + 1, 2)), positions, turn_rates=rng.normal(0, 0.5, m + 1))
    cov = np.tile(ODOMETRY_COV, (m, 1, 1)) * wheel_factor[:, None, None] + LASER_COV
    d = np.einsum("mij,mj->mi", np.linalg.cholesky(cov), rng.standard_normal((m, 3)))
    dis = Disagreement(d, np.tile(ODOMETRY_COV, (m, 1, 1)), np.tile(LASER_COV, (m, 1, 1)))
    monkeypatch.setattr(disagreement_mod, "disagreement", lambda *args: dis)
    pose = np.arange(m)
    edges = Edges(pose, pose, pose, pose + 1)
    return Models(data, None, edges, None, Fit(None, None, {}, 0.0), [], [])


def _lr(models, name):
    """evidence.evaluate's likelihood ratio of `name` on top of no effect, and the effect."""
    fit, noise, cost = models.fit_whole([name])
    return models.fit_whole([])[2] - cost, noise[0]


@pytest.mark.parametrize("name", ["noise_vs_speed", "noise_vs_turn_rate", "noise_vs_acceleration"])
def test_no_change_has_no_likelihood_ratio_with_exact_encoders(monkeypatch, name):
    # Exact encoders: the wheels' true share is 0, the disagreements are the laser's.
    models = _models(monkeypatch, np.random.default_rng(5), 600, np.zeros(600))
    lr, effect = _lr(models, name)
    assert effect.value() == pytest.approx(1.0, abs=1e-3)
    # With no change the extended model is the base model: the two NLLs are the same
    # function at the same factors, so they agree to rounding (600 edges, ~-10 nats each:
    # 1e-6 nats is far above float rounding and far below any χ² quantile).
    assert abs(lr) < 1e-6


@pytest.mark.parametrize("level", [1.0, 0.05])
def test_no_change_has_a_likelihood_ratio_of_chance(monkeypatch, level):
    """Noise that does not follow the speed, the base's level right (1) or 20 times too
    high (0.05): the fitted ratio is near 1 and its likelihood ratio that of one free
    parameter under no effect (χ²₁: below 6.6 with probability 0.99; seeds fixed)."""
    for seed in range(5):
        models = _models(monkeypatch, np.random.default_rng(10 + seed), 600, np.full(600, level))
        lr, effect = _lr(models, "noise_vs_speed")
        assert effect.value() == pytest.approx(1.0, abs=0.5)
        assert -1e-6 < lr < 6.6


def test_a_noise_growing_with_speed_keeps_its_likelihood_ratio(monkeypatch):
    """The same fit with variance growing with the speed, under a base level far off:
    the ratio is found and its likelihood ratio is far above the BIC penalty."""
    rng = np.random.default_rng(6)
    m = 600
    models = _models(monkeypatch, rng, m, np.ones(m))
    v = models.effects(["noise_vs_speed"])[0]._regressor(np.arange(m), np.arange(m))
    models = _models(monkeypatch, np.random.default_rng(6), m, 0.1 * np.exp(3.0 * v))
    lr, effect = _lr(models, "noise_vs_speed")
    assert effect.value() > 3.0
    assert lr > 3 * np.log(m)
