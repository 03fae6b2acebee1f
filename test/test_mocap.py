"""Odometry calibration against motion capture (marker = pose sensor with unknown mount)."""
from pathlib import Path

import numpy as np
import pytest

from sclam_ros.core import kinematics, mocap, se2
from sclam_ros.io.convert import optiodom_params, read_optiodom
from sclam_ros.core.params import SclamParams

DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "optiodom-diff"


TRUE_K = np.array([0.041, 0.0425, 0.21])
MOUNT = np.array([0.03, -0.02, 0.4])
TPR = 2796.8


def _synthetic_run(n=2000, marker_noise=2e-4, seed=3):
    """(stamps, ticks, marker poses, true body poses) of a robot with TRUE_K and MOUNT."""
    rng = np.random.default_rng(seed)
    speeds = np.cumsum(rng.normal(0, 0.3, (n, 2)), axis=0) * 0.02 + 1.0  # rad per cycle
    speeds[:, 1] += np.sin(np.arange(n) / 80.0)
    poses = [np.zeros(3)]
    for motion in kinematics.forward(speeds, TRUE_K):
        poses.append(se2.compose(poses[-1], motion))
    poses = np.array(poses)
    marker = se2.compose(poses, MOUNT)
    marker[:, :2] += rng.normal(0, marker_noise, (n + 1, 2))
    ticks = np.vstack([[0, 0], np.cumsum(speeds, axis=0)]) * TPR / (2 * np.pi)
    return np.arange(n + 1) * 0.05, ticks, marker, poses


def _params():
    return SclamParams(ticks_per_revolution=TPR, wheel_radius_left=0.042,
                       wheel_radius_right=0.042, wheel_base=0.2)


def test_recovers_synthetic_radii_base_and_marker_mount():
    stamps, ticks, marker, _ = _synthetic_run()
    cal = mocap.calibrate_with_ground_truth(stamps, ticks, marker, _params())
    assert np.allclose(cal.estimate[:3], TRUE_K, rtol=2e-3), cal.estimate
    assert np.allclose(cal.estimate[3:], MOUNT, atol=5e-3), cal.estimate


def test_mount_alone_with_k_held():
    stamps, ticks, marker, _ = _synthetic_run()
    cal = mocap.calibrate_with_ground_truth(stamps, ticks, marker, _params(), fixed_k=TRUE_K)
    assert np.array_equal(cal.estimate[:3], TRUE_K) and np.all(cal.sigma[:3] == 0)
    assert np.allclose(cal.estimate[3:], MOUNT, atol=5e-3), cal.estimate


def test_dead_reckoning_windows_exact_with_truth_and_heading_error_of_a_wrong_base():
    _, ticks, marker, poses = _synthetic_run(marker_noise=0.0)
    trans, heading = mocap.dead_reckoning_errors(ticks, marker, TRUE_K, MOUNT, TPR)
    assert len(trans) > 80 and trans.max() < 1e-9 and heading.max() < 1e-9
    # A base 5 % too long turns every window by 1/1.05 of its true rotation.
    wrong = TRUE_K * [1, 1, 1.05]
    _, heading = mocap.dead_reckoning_errors(ticks, marker, wrong, MOUNT, TPR, window=60, stride=30)
    _, rotation = kinematics.arc_length_and_rotation(np.diff(ticks, axis=0) * 2 * np.pi / TPR, TRUE_K)
    turned = np.array([rotation[s:s + 60].sum() for s in range(0, len(poses) - 60, 30)])  # unwrapped
    expected = np.abs(se2.wrap_angle(turned * (1 / 1.05 - 1)))
    assert np.allclose(heading, expected, atol=1e-9)


def test_dead_reckoning_lag_realigns_late_ticks():
    _, ticks, marker, _ = _synthetic_run(marker_noise=0.0)
    late = np.vstack([ticks[:1], ticks[:-1]])  # the mocap of cycle c meets the ticks of c − 1
    trans0, _ = mocap.dead_reckoning_errors(late, marker, TRUE_K, MOUNT, TPR)
    trans1, heading1 = mocap.dead_reckoning_errors(late, marker, TRUE_K, MOUNT, TPR, lag=1)
    assert trans0.max() > 1e-3 and trans1.max() < 1e-9 and heading1.max() < 1e-9


@pytest.mark.skipif(not DATA.is_dir(), reason=f"{DATA} not present")
@pytest.mark.parametrize("shape", ["circular", "square"])
def test_optiodom_run_calibrates_near_the_nominal_robot(shape):
    run = sorted((DATA / shape).glob("*/*_run-??.csv"))[0]
    stamps, truth, ticks = read_optiodom(run)
    cal = mocap.calibrate_with_ground_truth(stamps, ticks, truth, optiodom_params())
    r_l, r_r, b = cal.estimate[:3]
    assert r_l == pytest.approx(0.042, rel=0.03) and r_r == pytest.approx(0.042, rel=0.03)
    assert b == pytest.approx(0.2, rel=0.06)
    assert np.all(cal.sigma[:3] < [0.002, 0.002, 0.02])
