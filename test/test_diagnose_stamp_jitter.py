"""The scans' stamp jitter belongs to the model every effect is tested against.

A scan stamped δ off its time is compared with the wheels' motion to a pose δ off: the
disagreement grows with the laser's velocity, as wheel noise growing with speed or turn
rate would. With encoders that do not slip, the jitter is most of the disagreement.
"""
import dataclasses

import numpy as np
import pytest

from sclam_ros.core import se2
from sclam_ros.core.params import SclamParams
from sclam_ros.diagnosis.config import DiagnoseConfig
from sclam_ros.diagnosis.diagnose import diagnose_keyframes
from sclam_ros.diagnosis.stamp_jitter import laser_twists, stamp_covariance
from sclam_ros.io.recording import read_recording
from sclam_ros.sim import simulate
from sclam_ros.sim.conditions import RecordingConditions


def _arc(twist, t):
    """The pose after t s at a constant body twist (v, 0, ω) from the origin (exact arc)."""
    v, w = twist[0], twist[2]
    if abs(w) < 1e-12:
        return np.array([v * t, 0.0, 0.0])
    return np.array([v / w * np.sin(w * t), v / w * (1.0 - np.cos(w * t)), w * t])


def test_stamp_covariance_matches_monte_carlo_of_jittered_stamps():
    # A robot on an arc, the laser off its axle and turned: the laser's motion between two
    # scans whose stamps are off by independent δ, compared with the covariance formula.
    rng = np.random.default_rng(0)
    k, mount = np.array([0.1, 0.1, 0.5]), np.array([0.2, -0.05, 0.3])
    wheel_speeds = np.array([[6.0, 9.0]])  # rad/s: v 0.75 m/s, ω 0.6 rad/s
    r_l, r_r, b = k
    body = np.array([0.5 * (9.0 * r_r + 6.0 * r_l), 0.0, (9.0 * r_r - 6.0 * r_l) / b])
    dt, sigma = 0.3, 0.004

    def laser_motion(t_i, t_j):
        motion = se2.between(_arc(body, t_j), _arc(body, t_i))
        return se2.compose(se2.inverse(mount), se2.compose(motion, mount))

    zp = laser_motion(0.0, dt)
    samples = np.array([se2.between(laser_motion(d[0], dt + d[1]), zp)
                        for d in sigma * rng.standard_normal((20000, 2))])
    twist = laser_twists(wheel_speeds, k, mount)
    d_zp = se2.between_with_jacobians(zp[None], zp[None])[1]
    predicted = stamp_covariance(zp[None], d_zp, twist, twist)[0] * sigma**2
    measured = np.cov(samples.T)
    assert np.sqrt(np.diag(measured)) == pytest.approx(np.sqrt(np.diag(predicted)), rel=0.03)
    corr = measured[0, 1] / np.sqrt(measured[0, 0] * measured[1, 1])
    assert corr == pytest.approx(predicted[0, 1] / np.sqrt(predicted[0, 0] * predicted[1, 1]),
                                 abs=0.03)


@pytest.fixture(scope="module")
def jittered_exact(tmp_path_factory):
    """Encoders that do not slip, scans stamped with 2 ms of jitter; no effect at all."""
    bag = tmp_path_factory.mktemp("jitter") / "bag"
    simulate(bag, duration=120.0, seed=3, slip_noise=0.0, overwrite=True,
             conditions=RecordingConditions(no_return="zero", scan_stamp_jitter=0.002,
                                            scan_phase=0.007))
    params = SclamParams.from_yaml(bag / "params.yaml")
    return read_recording(bag, params, keep_scan_points=True).keyframes, params


def test_stamp_jitter_is_not_taken_for_wheel_noise(jittered_exact):
    keyframes, params = jittered_exact
    report = diagnose_keyframes(keyframes, params).report
    assert [e["name"] for e in report["effects"] if e["selected"]] == []
    assert 0.0005 < report["timing_noise_s"] < 0.004


def test_without_the_jitter_in_the_model_it_passes_for_wheel_noise(jittered_exact):
    # What the jitter in the model is for: the same recording tested against a model
    # without it selects a noise effect that is not there.
    keyframes, params = jittered_exact
    config = DiagnoseConfig()
    config = dataclasses.replace(config, noise=dataclasses.replace(config.noise, stamp_jitter=False))
    report = diagnose_keyframes(keyframes, params, config=config).report
    assert report["timing_noise_s"] is None
    selected = [e["name"] for e in report["effects"] if e["selected"]]
    assert any(name.startswith("noise_vs_") for name in selected)
