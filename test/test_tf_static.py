"""The nominal laser pose from a recording's /tf_static, unless the parameters file sets it."""
import json
import logging
import math

import numpy as np
import pytest
import yaml

from sclam_ros.cli.main import main
from sclam_ros.core.inputs import Scan
from sclam_ros.core.params import LASER_KEYS, SclamParams
from sclam_ros.io.bag import BagWriter, iter_messages, topic_info
from sclam_ros.io.tf_static import LaserMountError, with_nominal_laser_pose
from sclam_ros.sim import simulate


def _quat(roll=0.0, pitch=0.0, yaw=0.0):
    """(x, y, z, w) of ZYX Euler angles."""
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    return (sr * cp * cy - cr * sp * sy, cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy, cr * cp * cy + sr * sp * sy)


# base_footprint → base_link → laser_mount → laser, as robot_state_publisher latches a URDF;
# the laser 0.2 m ahead of and 0.05 m left of base_link, turned by 30° + 10°.
TREE = [
    ("base_footprint", "base_link", (0.0, 0.0, 0.05), _quat()),
    ("base_link", "laser_mount", (0.2, 0.05, 0.3), _quat(yaw=math.radians(30))),
    ("laser_mount", "laser", (0.0, 0.0, 0.02), _quat(yaw=math.radians(10))),
    ("base_link", "wheel_left", (0.0, 0.2, 0.0), _quat(roll=-math.pi / 2)),
]


def _bag(path, transforms, frame_id="laser"):
    with BagWriter(path) as bag:
        bag.write_tf_static(100.0, transforms)
        for i in range(3):
            bag.write_scan("/scan", Scan(stamp=100.0 + 0.1 * i, ranges=np.full(10, 2.0),
                                         angle_min=-1.0, angle_increment=0.2, range_min=0.1,
                                         range_max=10.0, frame_id=frame_id))
    return path


def _params(tmp_path, **values):
    path = tmp_path / "params.yaml"
    path.write_text(yaml.safe_dump({"sclam": {"ros__parameters": {"wheel_base": 0.4, **values}}}))
    return SclamParams.from_yaml(path)


def test_params_file_records_the_keys_it_set(tmp_path):
    params = _params(tmp_path, laser_x=0.1)
    assert params.explicit_keys == {"wheel_base", "laser_x"}
    assert params == SclamParams(wheel_base=0.4, laser_x=0.1)  # not a parameter itself


def test_tf_static_gives_the_nominal_laser_pose_when_the_file_does_not(tmp_path):
    bag = _bag(tmp_path / "bag", TREE)
    params, source = with_nominal_laser_pose(bag, _params(tmp_path))
    assert params.laser_x == pytest.approx(0.2, abs=1e-9)
    assert params.laser_y == pytest.approx(0.05, abs=1e-9)
    assert params.laser_yaw == pytest.approx(math.radians(40), abs=1e-9)
    assert params.wheel_base == 0.4
    assert "from /tf_static base_link → laser_mount → laser" in source


def test_parameters_file_wins(tmp_path):
    bag = _bag(tmp_path / "bag", TREE)
    params, source = with_nominal_laser_pose(
        bag, _params(tmp_path, laser_x=-0.1, laser_y=0.0, laser_yaw=0.0))
    assert (params.laser_x, params.laser_y, params.laser_yaw) == (-0.1, 0.0, 0.0)
    assert source.startswith("nominal laser pose from the parameters file")
    # Each name the file sets wins; the others come from /tf_static.
    params, source = with_nominal_laser_pose(bag, _params(tmp_path, laser_yaw=0.0))
    assert params.laser_yaw == 0.0 and params.laser_x == pytest.approx(0.2, abs=1e-9)
    assert "laser_x, laser_y from /tf_static" in source
    assert "laser_yaw from the parameters file" in source


def test_laser_beside_the_base_frame_is_found_through_their_common_parent(tmp_path):
    tree = [("base_footprint", "base_link", (0.1, 0.0, 0.05), _quat(yaw=math.radians(90))),
            ("base_footprint", "laser", (0.1, 0.3, 0.2), _quat(yaw=math.radians(90)))]
    params, source = with_nominal_laser_pose(_bag(tmp_path / "bag", tree), _params(tmp_path))
    # 0.3 m to the base's left in base_footprint is 0.3 m ahead of the turned base_link.
    assert params.laser_x == pytest.approx(0.3, abs=1e-9)
    assert params.laser_y == pytest.approx(0.0, abs=1e-9)
    assert params.laser_yaw == pytest.approx(0.0, abs=1e-9)
    assert "base_link → base_footprint → laser" in source


def test_no_chain_keeps_the_parameters(tmp_path):
    bag = _bag(tmp_path / "bag", TREE, frame_id="other_laser")
    params, source = with_nominal_laser_pose(bag, _params(tmp_path))
    assert (params.laser_x, params.laser_y, params.laser_yaw) == (0.0, 0.0, 0.0)
    assert "the defaults" in source


def test_tilted_laser_is_warned_about(tmp_path, caplog):
    tree = [("base_link", "laser", (0.2, 0.0, 0.3), _quat(pitch=math.radians(5)))]
    with caplog.at_level(logging.WARNING, logger="sclam"):
        params, _ = with_nominal_laser_pose(_bag(tmp_path / "bag", tree), _params(tmp_path))
    assert params.laser_x == pytest.approx(0.2, abs=1e-9)
    assert "tilted" in caplog.text and "pitch 5.0 deg" in caplog.text
    caplog.clear()
    tree = [("base_link", "laser", (0.2, 0.0, 0.3), _quat(pitch=math.radians(0.5)))]
    with caplog.at_level(logging.WARNING, logger="sclam"):
        with_nominal_laser_pose(_bag(tmp_path / "bag2", tree), _params(tmp_path))
    assert "tilted" not in caplog.text  # within a degree: a mount's tolerance


def test_upside_down_laser_is_refused(tmp_path):
    """Scans in a frame whose z points down are mirrored: the planar model cannot fit them
    (it would see the robot turn the other way), whatever the nominal pose."""
    for rotation in (_quat(roll=math.pi), _quat(pitch=math.pi, yaw=math.pi)):
        bag = _bag(tmp_path / f"bag{rotation}", [("base_link", "laser", (0.2, 0.0, 0.3), rotation)])
        with pytest.raises(LaserMountError, match="mounted upside down"):
            with_nominal_laser_pose(bag, _params(tmp_path, laser_x=0.2, laser_y=0.0, laser_yaw=0.0))


def params_without_laser_pose(sim) -> str:
    """A copy of a simulated recording's params.yaml without laser_*, beside it."""
    raw = yaml.safe_load((sim / "params.yaml").read_text())
    for key in LASER_KEYS:
        del raw["sclam"]["ros__parameters"][key]
    path = sim.parent / f"{sim.name}.no_laser.yaml"
    path.write_text(yaml.safe_dump(raw))
    return str(path)


def test_calibrate_prints_and_uses_the_tf_static_pose(tmp_path, capsys):
    """`sclam calibrate` on a simulated recording with /tf_static added and a parameters file
    without laser_*: the nominal laser pose is the latched one, and it says so."""
    sim = tmp_path / "sim"
    truth = simulate(sim, robot="pioneer", duration=20.0, seed=2)
    mount = [truth["laser_x"], truth["laser_y"], truth["laser_yaw"]]
    bag = tmp_path / "bag"
    with BagWriter(bag) as out:
        out.write_tf_static(0.0, [("base_link", "laser", (mount[0], mount[1], 0.3),
                                   _quat(yaw=mount[2]))])
        info = topic_info(sim)
        for topic, t, msg in iter_messages(sim, sorted(info)):
            out.write(topic, info[topic][0], msg, t)
    rc = main(["calibrate", str(bag), "--params", params_without_laser_pose(sim), "--quiet",
               "--json", str(tmp_path / "c.json")])
    assert rc == 0
    assert "nominal laser pose from /tf_static base_link → laser" in capsys.readouterr().out
    nominal = json.loads((tmp_path / "c.json").read_text())["nominal"]
    assert [nominal[k] for k in LASER_KEYS] == pytest.approx(mount, abs=1e-9)
