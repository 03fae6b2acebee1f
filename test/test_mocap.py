"""Odometry calibration against motion capture (marker = pose sensor with unknown mount)."""
from pathlib import Path

import numpy as np
import pytest

from sclam_ros import kinematics, mocap, se2
from sclam_ros.convert import optiodom_params, read_optiodom
from sclam_ros.params import SclamParams

DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "optiodom-diff"


def test_recovers_synthetic_radii_base_and_marker_mount():
    rng = np.random.default_rng(3)
    true_k = np.array([0.041, 0.0425, 0.21])
    mount = np.array([0.03, -0.02, 0.4])
    n = 2000
    speeds = np.cumsum(rng.normal(0, 0.3, (n, 2)), axis=0) * 0.02 + 1.0  # rad per cycle
    speeds[:, 1] += np.sin(np.arange(n) / 80.0)
    poses = [np.zeros(3)]
    for motion in kinematics.forward(speeds, true_k):
        poses.append(se2.compose(poses[-1], motion))
    marker = se2.compose(np.array(poses), mount)
    marker[:, :2] += rng.normal(0, 2e-4, (n + 1, 2))
    tpr = 2796.8
    ticks = np.vstack([[0, 0], np.cumsum(speeds, axis=0)]) * tpr / (2 * np.pi)
    params = SclamParams(ticks_per_revolution=tpr, wheel_radius_left=0.042,
                         wheel_radius_right=0.042, wheel_base=0.2)
    cal = mocap.calibrate_with_ground_truth(np.arange(n + 1) * 0.05, ticks, marker, params)
    assert np.allclose(cal.estimate[:3], true_k, rtol=2e-3), cal.estimate
    assert np.allclose(cal.estimate[3:], mount, atol=5e-3), cal.estimate


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
