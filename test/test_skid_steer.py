"""A four-wheel skid-steer (issue 59): each side's wheels averaged, calibrated as an effective
wheel base, exported as diff_drive_controller's wheel_separation_multiplier.

End to end on one simulated drive (sim/motion.TrueKinematics: the sides' centres of rotation
at ±χ·B/2, χ = 2), checked against the simulator's truth, never against printed numbers.
"""
from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import yaml
from rclpy.parameter import parameter_dict_from_yaml_file

from fuzz_cases import rewrite, wrap_counter
from sclam_ros.cli.main import main
from sclam_ros.core.params import ParamsError, SclamParams
from sclam_ros.frontend.wheel_sides import SideDisagreement
from sclam_ros.io.messages import MessageRejected, joint_state_to_raw
from sclam_ros.sim import simulate
from sclam_ros.sim.record import SKID_JOINT_NAMES

FL, RL, FR, RR = SKID_JOINT_NAMES
SKID = SclamParams(left_wheel_joints=(FL, RL), right_wheel_joints=(FR, RR))
RADII = ("wheel_radius_left", "wheel_radius_right")


def joint_state(names, positions, sec=3):
    stamp = SimpleNamespace(sec=sec, nanosec=0)
    return SimpleNamespace(header=SimpleNamespace(stamp=stamp), name=list(names),
                           position=np.asarray(positions, float))


# --- conversion and parameters ---------------------------------------------------------------


def test_a_sides_wheels_are_averaged():
    msg = joint_state(["caster", RR, FL, FR, RL], [9.0, 4.0, 1.0, 2.0, 3.0])
    assert joint_state_to_raw(msg, SKID) == (3.0, 2.0, 3.0)


def test_wrapping_counters_are_averaged_around_the_modulus():
    params = dataclasses.replace(SKID, encoder_wrap=100.0)
    before = joint_state_to_raw(joint_state([FL, RL, FR, RR], [99.0, 97.0, 10.0, 10.0]), params)
    after = joint_state_to_raw(joint_state([FL, RL, FR, RR], [1.0, 99.0, 12.0, 12.0]), params)
    # Both left wheels moved +2 ticks, one of them across the wrap: the mean moves 2 mod 100.
    assert (after[1] - before[1]) % 100.0 == pytest.approx(2.0)


def test_a_message_missing_one_wheel_of_a_side_is_rejected_naming_it():
    with pytest.raises(MessageRejected) as err:
        joint_state_to_raw(joint_state([FL, FR, RR], [1.0, 2.0, 3.0]), SKID)
    assert err.value.reason == "joint_state_missing_joint" and RL in str(err.value)


@pytest.mark.parametrize("values, needle", [
    ({"left_wheel_joints": ["a", "b"]}, "set left_wheel_joints and right_wheel_joints together"),
    ({"left_wheel_joints": ["a", "b"], "right_wheel_joints": ["c"]}, "as many wheels"),
    ({"left_wheel_joints": ["a", "b"], "right_wheel_joints": ["b", "c"]}, "named on both sides"),
    ({"left_wheel_joints": ["a", "a"], "right_wheel_joints": ["b", "c"]}, "names a joint twice"),
    ({"left_wheel_joints": "a, b", "right_wheel_joints": ["b", "c"]}, "must be a list"),
])
def test_bad_wheel_joint_lists_are_one_line_errors(values, needle):
    with pytest.raises(ParamsError, match=needle):
        SclamParams.from_dict(values)


def test_wheel_joint_lists_round_trip_through_the_parameters_file(tmp_path):
    params = dataclasses.replace(SKID, wheel_separation=0.5)
    params.write_yaml(tmp_path / "p.yaml")
    again = SclamParams.from_yaml(tmp_path / "p.yaml")
    assert again.wheel_joints() == ((FL, RL), (FR, RR)) and again.wheels_per_side == 2
    assert again == params


def test_a_joint_of_the_other_side_spreads_the_side():
    sides = SideDisagreement(dataclasses.replace(SKID, ticks_per_revolution=0.0))
    angle = np.linspace(0.0, 60.0, 600)  # rad: the left side rolls on, the right turns less
    for left, right in zip(angle, 0.5 * angle):
        sides.add([left, right], [right, right])  # rear_left is really a right wheel
    summary = sides.summary()
    assert summary["left"]["rms_percent"] > 50.0 and summary["right"]["rms_percent"] == 0.0
    assert len(sides.warnings()) == 1 and "left_wheel_joints" in sides.warnings()[0]


# --- end to end --------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def skid_bag(tmp_path_factory):
    out = tmp_path_factory.mktemp("skid") / "bag"
    truth = simulate(out, robot="skid", duration=120.0, seed=3, track_widening=2.0)
    return out, truth


def _calibrate(bag, tmp_path, params=None, name="cal"):
    out = tmp_path / f"{name}.json"
    rc = main(["calibrate", str(bag), "--params", str(params or bag / "params.yaml"),
               "--json", str(out), "--quiet"])
    assert rc == 0
    return json.loads(out.read_text())


def _assert_close_to_truth(cal, truth):
    assert abs(cal["wheel_base"] / truth["wheel_base"] - 1.0) < 0.005
    for key in RADII:
        assert abs(cal[key] / truth[key] - 1.0) < 0.002


def test_effective_wheel_base_calibrated_and_exported_as_multiplier(skid_bag, tmp_path):
    bag, truth = skid_bag
    assert truth["wheel_base"] == pytest.approx(2.0 * truth["wheel_separation"])
    cal = _calibrate(bag, tmp_path)
    _assert_close_to_truth(cal, truth)
    for side in cal["wheel_sides"].values():  # slip noise only: well below the warning
        assert side["stretches"] > 10 and side["rms_percent"] < 1.5

    out = tmp_path / "controller.yaml"
    assert main(["export", str(tmp_path / "cal.json"), "--format", "diff-drive",
                 "--out", str(out)]) == 0
    block = yaml.safe_load(out.read_text())["diff_drive_controller"]["ros__parameters"]
    assert block["wheels_per_side"] == 2
    assert block["wheel_separation"] == pytest.approx(truth["wheel_separation"])
    effective = block["wheel_separation"] * block["wheel_separation_multiplier"]
    assert abs(effective / truth["wheel_base"] - 1.0) < 0.005
    for key, multiplier in zip(RADII, ("left_wheel_radius_multiplier",
                                       "right_wheel_radius_multiplier")):
        assert abs(block["wheel_radius"] * block[multiplier] / truth[key] - 1.0) < 0.002
    # As ROS 2 loads a parameters file: the controller declares wheels_per_side an integer
    # and the rest doubles.
    loaded = parameter_dict_from_yaml_file(str(out), target_nodes=["diff_drive_controller"])
    types = {name: p.value.type for name, p in loaded.items()}
    assert types.pop("wheels_per_side") == 2  # ParameterType.PARAMETER_INTEGER
    assert set(types.values()) == {3}  # ParameterType.PARAMETER_DOUBLE
    assert loaded["wheel_separation_multiplier"].value.double_value == pytest.approx(
        block["wheel_separation_multiplier"])


def test_wrapping_counters_calibrate_as_well(skid_bag, tmp_path):
    bag, truth = skid_bag
    wrapped = rewrite(bag, tmp_path / "wrapped", change_joint_state=lambda i, m: wrap_counter(4096)(m))
    params = (wrapped / "params.yaml").read_text().replace("encoder_wrap: 0.0", "encoder_wrap: 4096")
    (tmp_path / "p.yaml").write_text(params)
    _assert_close_to_truth(_calibrate(wrapped, tmp_path, tmp_path / "p.yaml"), truth)


def _drop(joint, every):
    def change(i, msg):
        if i % every:
            return msg
        keep = [n != joint for n in msg.name]
        return dataclasses.replace(msg, name=[n for n, k in zip(msg.name, keep) if k],
                                   position=np.asarray(msg.position)[keep])
    return change


def test_messages_missing_a_wheel_are_counted_and_the_rest_used(skid_bag, tmp_path, capsys):
    bag, truth = skid_bag
    holes = rewrite(bag, tmp_path / "holes", change_joint_state=_drop(RL, 10))
    cal = _calibrate(holes, tmp_path)
    assert cal["rejected"]["joint_state_missing_joint"] == math.ceil(
        cal["messages"]["/joint_states"]["read"] / 10)
    assert any(RL in line for line in cal["warnings"])
    _assert_close_to_truth(cal, truth)


@pytest.mark.parametrize("case, needles", [
    ("absent", ["wheel joint(s) rear_left_wheel_joint not in /joint_states",
                "set left_wheel_joints and right_wheel_joints"]),
    ("misnamed", ["wheel joint(s) rear_left not in /joint_states", "set left_wheel_joints"]),
    ("split", ["separate messages", "publish them in one JointState"]),
])
def test_wheel_joints_not_in_the_recording_are_a_one_line_error(skid_bag, tmp_path, capsys,
                                                                  case, needles):
    bag, _ = skid_bag
    params = bag / "params.yaml"
    if case == "absent":
        bag = rewrite(bag, tmp_path / "bad", change_joint_state=_drop(RL, 1))
    elif case == "misnamed":
        params = tmp_path / "p.yaml"
        params.write_text((bag / "params.yaml").read_text().replace(f"- {RL}", "- rear_left"))
    else:
        def split(i, msg):  # the front wheels in even messages, the rear ones in odd
            keep = [("front" in n) == (i % 2 == 0) for n in msg.name]
            return dataclasses.replace(msg, name=[n for n, k in zip(msg.name, keep) if k],
                                       position=np.asarray(msg.position)[keep])
        bag = rewrite(bag, tmp_path / "bad", change_joint_state=split)
    rc = main(["calibrate", str(bag), "--params", str(params), "--quiet"])
    err = capsys.readouterr().err
    assert rc == 2
    line = [x for x in err.splitlines() if "error:" in x]
    assert len(line) == 1 and all(n in line[0] for n in needles), err


def test_the_node_reads_the_skid_steer_parameters_file():
    """sclam_node declares the joint lists as ROS 2 parameters and reads them from the
    example parameters file, as `--ros-args --params-file` passes it."""
    import os

    import rclpy
    from rclpy.parameter import Parameter

    from sclam_ros.ros.node import SclamNode

    path = Path(__file__).parents[1] / "launch_configs" / "config" / "skid_steer.yaml"
    raw = yaml.safe_load(path.read_text())["sclam"]["ros__parameters"]
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=100 + os.getpid() % 100)
    try:
        node = SclamNode(context=context, parameter_overrides=[
            Parameter(k, value=v) for k, v in raw.items()])
        try:
            assert node.params == SclamParams.from_yaml(path)
            assert node.params.wheel_joints() == ((FL, RL), (FR, RR))
        finally:
            node.destroy_node()
    finally:
        rclpy.shutdown(context=context)
