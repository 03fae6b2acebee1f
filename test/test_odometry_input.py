"""Robots that publish wheel odometry (nav_msgs/Odometry) instead of their wheels' JointState:
odometry_topic, its increments turned back into wheel rotations with the nominal values."""
import dataclasses
import json

import numpy as np
import pytest

from sclam_ros.cli.main import main
from sclam_ros.core import kinematics, se2
from sclam_ros.core.estimator import calibrate_keyframes
from sclam_ros.core.params import CALIBRATION_KEYS, ParamsError, SclamParams
from sclam_ros.frontend.odometry_wheels import WheelsFromOdometry
from sclam_ros.io.recording import read_recording
from sclam_ros.sim import simulate


@pytest.fixture(scope="module")
def both(tmp_path_factory):
    """One drive recorded with /joint_states and /odom (integrated from the same encoder
    samples with the nominal values, as diff_drive_controller does)."""
    out = tmp_path_factory.mktemp("both") / "bag"
    truth = simulate(out, robot="powerbot", duration=90.0, seed=4, wheels="both")
    joint_states = SclamParams.from_yaml(out / "params.yaml")
    odometry = dataclasses.replace(joint_states, odometry_topic="/odom",
                                   ticks_per_revolution=0.0).validate()
    return out, truth, joint_states, odometry


def _calibrate(bag, params):
    recording = read_recording(bag, params)
    return calibrate_keyframes(recording.keyframes, params, recording.rejections)


def test_odometry_calibrates_as_the_joint_states_it_came_from(both):
    bag, truth, joint_states, odometry = both
    from_joints, from_odom = _calibrate(bag, joint_states), _calibrate(bag, odometry)
    assert from_joints.converged and from_odom.converged
    for key in CALIBRATION_KEYS:
        sigma = from_joints.sigma[key]
        assert abs(from_odom.estimate[key] - from_joints.estimate[key]) < 0.3 * sigma, key
        assert from_odom.sigma[key] == pytest.approx(sigma, rel=0.05), key
        # Against the simulator's truth: a 90 s drive determines them to its σ.
        assert abs(from_odom.estimate[key] - truth[key]) < 3 * from_odom.sigma[key], key


def test_a_recording_with_only_odom_runs_from_its_params_file(tmp_path, capsys):
    bag = tmp_path / "bag"
    truth = simulate(bag, robot="pioneer", duration=40.0, seed=6, wheels="odom")
    assert "joint_states" not in truth["topics"] and truth["topics"]["odometry"] == "/odom"
    rc = main(["calibrate", str(bag), "--params", str(bag / "params.yaml"), "--json",
               str(tmp_path / "c.json"), "--quiet"])
    assert rc == 0
    result = json.loads((tmp_path / "c.json").read_text())
    assert result["messages"]["/odom"]["used"] == result["messages"]["/odom"]["read"] > 1500
    assert result["warnings"] == []  # a differential drive's own odometry: nothing sideways
    # The online calibrator reads it through the same reader.
    rc = main(["calibrate", str(bag), "--params", str(bag / "params.yaml"), "--track",
               str(tmp_path / "t.csv"), "--quiet"])
    assert rc == 0 and len((tmp_path / "t.csv").read_text().splitlines()) > 2


@pytest.mark.parametrize("change, says", [
    ({"base_frame": "base_footprint"}, "set base_frame: base_link"),
    ({"odometry_topic": "/scan"}, "odometry_topic /scan carries sensor_msgs/msg/LaserScan"),
    ({"odometry_topic": "/no_odom"}, "/no_odom not in bag"),
])
def test_unusable_odometry_is_a_one_line_error(both, tmp_path, capsys, change, says):
    bag, _, _, odometry = both
    dataclasses.replace(odometry, **change).write_yaml(tmp_path / "p.yaml")
    rc = main(["calibrate", str(bag), "--params", str(tmp_path / "p.yaml"), "--quiet"])
    err = [line for line in capsys.readouterr().err.splitlines() if ": error: " in line]
    assert rc == 2 and len(err) == 1 and says in err[0], err


def test_ticks_do_not_apply_to_odometry():
    with pytest.raises(ParamsError, match="ticks_per_revolution and encoder_wrap must be 0"):
        SclamParams(odometry_topic="/odom", ticks_per_revolution=4096).validate()


def _drive(k, steps=400, seed=0):
    """Poses and yaw rates of a differential drive's odometry at 20 Hz, and its wheel angles."""
    rng = np.random.default_rng(seed)
    dphi = np.column_stack([np.full(steps, 0.3), np.full(steps, 0.3)]) + rng.normal(0, 0.15, (steps, 2))
    motion = np.vstack([np.zeros(3), kinematics.forward(dphi, k)])
    yaw_rate = np.concatenate([[0.0], motion[1:, 2] / 0.05])
    return se2.chain(motion), yaw_rate, np.vstack([np.zeros(2), np.cumsum(dphi, axis=0)])


def _feed(params, poses, yaw_rate):
    wheels = WheelsFromOdometry(params)
    angles = [wheels.add(0.05 * i, pose, w) for i, (pose, w) in enumerate(zip(poses, yaw_rate))]
    return wheels, np.array(angles)


def test_wheel_odometry_gives_back_its_wheel_angles_and_raises_no_doubt():
    params = SclamParams(wheel_radius_left=0.1, wheel_radius_right=0.102, wheel_base=0.45)
    poses, yaw_rate, truth = _drive(np.array([0.1, 0.102, 0.45]))
    wheels, angles = _feed(params, poses, yaw_rate)
    np.testing.assert_allclose(angles, truth, atol=1e-9)
    assert wheels.sideways == 0 and not wheels.twist_disagrees()
    flipped = dataclasses.replace(params, left_encoder_sign=-1.0)
    _, angles = _feed(flipped, poses, yaw_rate)
    np.testing.assert_allclose(angles[:, 0], -truth[:, 0], atol=1e-9)


def test_fused_odometry_shows_as_sideways_motion_and_a_twist_that_turns_otherwise():
    params = SclamParams(wheel_radius_left=0.1, wheel_radius_right=0.1, wheel_base=0.45)
    poses, yaw_rate, _ = _drive(np.array([0.1, 0.1, 0.45]))
    # A heading from a gyro that reads 10 % less turning than the wheels, beside the wheels'
    # velocities in the twist; positions integrated along that heading drift sideways.
    motion = se2.between(poses[1:], poses[:-1])
    fused = motion * [1.0, 1.0, 0.9]
    fused[:, 1] += 0.002
    fused_poses = se2.chain(np.vstack([np.zeros(3), fused]))
    wheels, _ = _feed(params, fused_poses, yaw_rate)
    assert wheels.sideways > 0.9 * len(motion) and wheels.twist_disagrees()
