"""`sclam calibrate BAG` without a parameters file: what the recording and the robot's
description give, printed and written; a one-line error naming what they do not."""
import json

import numpy as np
import pytest

from sclam_ros.cli.main import main
from sclam_ros.core.inputs import Scan
from sclam_ros.core.params import CALIBRATION_KEYS, SclamParams
from sclam_ros.io.bag import BagWriter
from sclam_ros.sim import simulate
from sclam_ros.sim.description import laser_transform, robot_urdf

NOMINAL = dict(zip(CALIBRATION_KEYS, (0.1, 0.1, 0.4, 0.15, 0.02, 0.1)))


@pytest.mark.parametrize("wheels, joint_units", [("joint_states", "rad"), ("odom", "ticks")])
def test_calibrates_from_the_recording_alone_and_writes_what_it_inferred(
        tmp_path, capsys, wheels, joint_units):
    bag = tmp_path / "bag"
    truth = simulate(bag, robot="pioneer", duration=60.0, seed=8, wheels=wheels,
                     description=True, joint_units=joint_units)
    saved, first, second = tmp_path / "inferred.yaml", tmp_path / "a.json", tmp_path / "b.json"
    rc = main(["calibrate", str(bag), "--save-params", str(saved), "--json", str(first), "--quiet"])
    out = capsys.readouterr().out
    assert rc == 0 and "inferred from the recording" in out and str(saved) in out
    inferred = SclamParams.from_yaml(saved)
    # The description's values are the simulated robot's nominal ones.
    for key in CALIBRATION_KEYS:
        assert getattr(inferred, key) == pytest.approx(truth["nominal"][key], abs=1e-6), key
    assert (inferred.odometry_topic, inferred.joint_states_topic) == (
        ("/odom", "/joint_states") if wheels == "odom" else ("", "/joint_states"))
    assert "/odom" in out if wheels == "odom" else "/joint_states (left_wheel_joint" in out
    # The written file, passed back, is the same calibration.
    assert main(["calibrate", str(bag), "--params", str(saved), "--json", str(second),
                 "--quiet"]) == 0
    a, b = json.loads(first.read_text()), json.loads(second.read_text())
    for key in CALIBRATION_KEYS:
        assert a[key] == pytest.approx(b[key], abs=1e-12)
        if a["observable"][key]:
            assert abs(a[key] - truth[key]) < 4 * a["sigma"][key], key


def _scan(stamp):
    return Scan(stamp=stamp, ranges=np.full(90, 3.0), angle_min=-np.pi,
                angle_increment=2 * np.pi / 90, range_min=0.1, range_max=10.0,
                time_increment=0.0, frame_id="laser")


def _bag(path, urdf=None, scans=("/scan",), odometry_child="base_link", tf_static=True,
         joint_states=False):
    """A few messages of each kind a robot records, enough for the inference."""
    with BagWriter(path) as bag:
        if urdf is not None:
            bag.write_string("/robot_description", urdf, 1.0)
        if tf_static:
            bag.write_tf_static(1.0, [laser_transform(NOMINAL)])
        for i in range(5):
            t = 1.0 + 0.1 * i
            for topic in scans:
                bag.write_scan(topic, _scan(t))
            if odometry_child is not None:
                bag.write_odometry("/odom", t, (0.1 * i, 0.0, 0.0), child_frame_id=odometry_child)
            if joint_states:
                bag.write_joint_state("/joint_states", t, ["left_wheel_joint", "right_wheel_joint"],
                                      [0.0, 0.0])
    return path


def _without_wheels(urdf):
    return urdf.replace('type="continuous"', 'type="fixed"')


def _three_wheels(urdf):
    extra = ('<link name="third_wheel"><collision><geometry><cylinder radius="0.1" length="0.04"/>'
             '</geometry></collision></link><joint name="third_wheel_joint" type="continuous">'
             '<parent link="base_link"/><child link="third_wheel"/>'
             '<origin xyz="0.3 0.2 0.1"/><axis xyz="0 1 0"/></joint></robot>')
    return urdf.replace("</robot>", extra)


def _without_laser(urdf):
    return urdf.replace('<joint name="laser_joint" type="fixed">', '<!--').replace(
        '<origin xyz="0.15', '--><!-- ').replace('rpy="0 0 0.1"/>\n  </joint>', '-->')


URDF = robot_urdf("test", NOMINAL)


@pytest.mark.parametrize("bag_kwargs, says", [
    (dict(urdf=None), "no /robot_description (std_msgs/String)"),
    (dict(urdf=URDF, scans=("/scan", "/scan_rear")), "2 candidate LaserScan topics (/scan, /scan_rear)"),
    (dict(urdf=URDF, scans=()), "no sensor_msgs/LaserScan topic"),
    (dict(urdf=_without_wheels(URDF)), "no two wheel joints (continuous joints whose child links are cylinders"),
    (dict(urdf=_three_wheels(URDF)), "3 wheel joints"),
    (dict(urdf=URDF, odometry_child="chassis"), "/odom is the motion of chassis, which is not a link"),
    (dict(urdf=URDF, odometry_child=None), "no wheel input"),
    (dict(urdf=_without_laser(URDF), tf_static=False), "the laser's mount"),
    (dict(urdf="<robot name='x'><link name='a'/>", joint_states=True), "not a URDF (not XML"),
])
def test_what_cannot_be_inferred_is_a_one_line_error(tmp_path, capsys, bag_kwargs, says):
    bag = _bag(tmp_path / "bag", **bag_kwargs)
    rc = main(["calibrate", str(bag), "--save-params", str(tmp_path / "p.yaml"), "--quiet"])
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert rc == 2 and len(err) == 1 and says in err[0], err
    assert "--params" in err[0] or "record" in err[0] or "URDF" in err[0]
    assert not (tmp_path / "p.yaml").exists()


def test_a_laser_placed_only_by_the_description_is_read_from_it(tmp_path, capsys):
    bag = _bag(tmp_path / "bag", urdf=URDF, tf_static=False, joint_states=True)
    from sclam_ros.io.zero_config import infer_params

    params, lines = infer_params(bag)
    assert params.joint_states_topic == "/joint_states" and params.odometry_topic == ""
    assert (params.laser_x, params.laser_y, params.laser_yaw) == pytest.approx((0.15, 0.02, 0.1))
    assert any("/robot_description base_link → laser" in line for line in lines)
