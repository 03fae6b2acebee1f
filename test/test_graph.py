"""Graph construction: merged keyframes keep every measurement."""
import numpy as np
import pytest

from sclam_ros.core import se2
from sclam_ros.frontend.pipeline import Keyframe
from sclam_ros.core.config import GraphConfig
from sclam_ros.core.graph import chained_scan_match_covariance, merge_keyframes


def chain(n, rng, broken=()):
    kfs = [Keyframe(0, 0.0, np.zeros(2))]
    for i in range(1, n):
        kf = Keyframe(i, 0.1 * i, np.zeros(2), dphi=rng.normal(0.3, 0.1, 2))
        if i not in broken:
            kf.laser_from, kf.laser_motion = i - 1, rng.normal(0, 0.05, 3)
            kf.laser_information = np.eye(3) * 1e4
        kfs.append(kf)
    return kfs


def test_merging_adds_wheel_angles_and_composes_scan_matches():
    rng = np.random.default_rng(0)
    kfs = chain(21, rng)
    merged = merge_keyframes(kfs, 0.5)
    assert [m.stamp for m in merged] == pytest.approx([0.0, 0.5, 1.0, 1.5, 2.0])
    assert np.allclose(sum(m.dphi for m in merged[1:]), sum(k.dphi for k in kfs[1:]))
    z = np.zeros(3)
    for k in kfs[1:6]:
        z = se2.compose(z, k.laser_motion)
    assert np.allclose(merged[1].laser_motion, z)
    # Five matches of covariance 1e-4 I with lag-1 correlation ρ: (5 + 8ρ)·1e-4 I.
    rho = GraphConfig().scan_match_lag1_correlation
    expected = (5 + 8 * rho) * 1e-4 * np.eye(3)
    assert np.allclose(np.linalg.inv(merged[1].laser_information), expected)


def test_interpolation_variance_of_a_merged_edge_is_that_of_its_two_ends():
    """An increment is the difference of the interpolated angles at its ends: merged over
    several keyframes, the inner ends cancel, and its variance is the first and the last
    end's, not the sum over the parts."""
    from sclam_ros.core.graph import GraphInputs

    rng = np.random.default_rng(1)
    kfs = chain(21, rng)
    for kf in kfs:
        kf.angle_variance = np.array([1.0, 2.0]) * (kf.index + 1)
    merged = merge_keyframes(kfs, 0.5)
    inputs = GraphInputs.from_keyframes(merged)
    # Merged keyframe m ends at scan 5m; its edge starts where keyframe m − 1 ends.
    ends = [5 * m for m in range(len(merged))]
    expected = [np.array([1.0, 2.0]) * (a + 1 + b + 1) for a, b in zip(ends[:-1], ends[1:])]
    np.testing.assert_allclose(inputs.odo_variance, expected)
    assert GraphInputs.from_keyframes(chain(5, rng)).odo_variance is None  # sampled angles


def test_chained_covariance_matches_a_simulated_ma1_chain():
    """Errors that share a scan, e = n_i + θ n_{i−1} with θ = −0.5 (lag-1 correlation
    θ / (1 + θ²) = −0.4): the variance of their sum, sampled, against the formula."""
    rng = np.random.default_rng(4)
    theta, n, draws = -0.5, 5, 200_000
    noise = rng.standard_normal((draws, n + 1))
    errors = noise[:, 1:] + theta * noise[:, :-1]
    sampled = np.var(errors.sum(axis=1))
    part = np.array([[1 + theta**2]])  # variance of one error
    formula = chained_scan_match_covariance([part] * n)[0, 0]
    assert theta / (1 + theta**2) == pytest.approx(GraphConfig().scan_match_lag1_correlation)
    assert formula == pytest.approx(sampled, rel=0.02)
    assert formula < 0.5 * n * part[0, 0]  # far below the independent sum


def test_a_missing_scan_match_is_not_bridged():
    rng = np.random.default_rng(1)
    kfs = chain(21, rng, broken={7})
    merged = merge_keyframes(kfs, 0.5)
    # Wheel increments are all there: their sum is unchanged.
    assert np.allclose(sum(m.dphi for m in merged[1:]), sum(k.dphi for k in kfs[1:]))
    # The interval containing scan 7 carries no laser edge; all others do.
    no_laser = [m for m in merged[1:] if m.laser_motion is None]
    assert len(no_laser) == 1 and no_laser[0].stamp == pytest.approx(0.7)


def test_with_slow_encoders_a_merged_edge_ends_at_the_first_keyframe_after_a_sample():
    """Encoder samples every 1.0 s (at 0.05, 1.05, 2.05, ...), keyframes every 0.1 s: once
    the interval (0.5 s) has passed, an edge waits for the keyframe just after the next
    sample, where its wheel angles are nearly exact, instead of ending between samples."""
    rng = np.random.default_rng(2)
    kfs = chain(41, rng)
    for kf in kfs:
        kf.since_sample = round(kf.stamp - 0.05, 9) % 1.0
    merged = merge_keyframes(kfs, 0.5)
    # Edges end 50 ms after the samples at 1.05, 2.05 and 3.05 s (and at the end of data).
    assert [m.stamp for m in merged] == pytest.approx([0.0, 1.1, 2.1, 3.1, 4.0])
    assert np.allclose(sum(m.dphi for m in merged[1:]), sum(k.dphi for k in kfs[1:]))


def test_with_fast_encoders_edges_keep_the_interval():
    rng = np.random.default_rng(3)
    kfs = chain(21, rng)
    for kf in kfs:
        kf.since_sample = 0.004  # 50 Hz encoders: a sample between any two keyframes
    assert [m.stamp for m in merge_keyframes(kfs, 0.5)] == pytest.approx([0.0, 0.5, 1.0, 1.5, 2.0])


def test_with_slow_encoders_a_missing_scan_match_does_not_end_an_edge_between_samples():
    """The match at 1.3 s is missing, between the samples at 1.05 and 2.05 s: the edge from
    1.1 s goes on to the keyframe after the next sample without a laser part, instead of
    ending at 1.2 s where the wheel angles are a straight line's guess."""
    rng = np.random.default_rng(4)
    kfs = chain(41, rng, broken={13})
    for kf in kfs:
        kf.since_sample = round(kf.stamp - 0.05, 9) % 1.0
    merged = merge_keyframes(kfs, 0.5)
    assert [m.stamp for m in merged] == pytest.approx([0.0, 1.1, 2.1, 3.1, 4.0])
    assert [m.laser_motion is None for m in merged[1:]] == [False, True, False, False]
    assert np.allclose(sum(m.dphi for m in merged[1:]), sum(k.dphi for k in kfs[1:]))
