"""`sclam calibrate --urdf`: the nominal laser pose from the robot's URDF (parsed with yourdfpy),
below the parameters file and above /tf_static; a URDF it cannot use is one line, exit 2."""
import json
import math

import pytest

from sclam_ros.cli.main import main
from sclam_ros.core.params import LASER_KEYS
from sclam_ros.io.tf_static import with_nominal_laser_pose
from sclam_ros.sim import simulate
from test_tf_static import TREE, _bag, _params, params_without_laser_pose

# base_footprint → base_link → laser_mount → laser, the laser 0.1 m ahead on a mount turned by
# 30° (0.2 m ahead of and 0.05 m left of base_link), itself turned by 10° more; a wheel on a
# continuous joint beside the chain, and a mesh that is not there (never loaded).
JOINTS = [
    ("base_link_joint", "fixed", "base_footprint", "base_link", "0 0 0.05", "0 0 0"),
    ("laser_mount_joint", "fixed", "base_link", "laser_mount", "0.2 0.05 0.3",
     f"0 0 {math.radians(30)}"),
    ("laser_joint", "fixed", "laser_mount", "laser", "0.1 0 0.02", f"0 0 {math.radians(10)}"),
    ("left_wheel_joint", "continuous", "base_link", "left_wheel", "0 0.2 0", f"{-math.pi / 2} 0 0"),
]
EXPECTED = (0.2 + 0.1 * math.cos(math.radians(30)), 0.05 + 0.1 * math.sin(math.radians(30)),
            math.radians(40))


def _urdf(path, joints=JOINTS):
    links = dict.fromkeys(name for _, _, parent, child, _, _ in joints for name in (parent, child))
    text = ['<?xml version="1.0"?>', '<robot name="test_robot">']
    for link in links:
        text.append(f'  <link name="{link}"><visual><geometry><mesh filename='
                    f'"package://test_robot/meshes/{link}.stl"/></geometry></visual></link>')
    for name, kind, parent, child, xyz, rpy in joints:
        text.append(f'  <joint name="{name}" type="{kind}"><parent link="{parent}"/>'
                    f'<child link="{child}"/><origin xyz="{xyz}" rpy="{rpy}"/>'
                    + ('<axis xyz="0 0 1"/>' if kind != "fixed" else "") + "</joint>")
    path.write_text("\n".join(text + ["</robot>"]) + "\n")
    return path


def _laser_pose(params):
    return params.calibration_vector()[3:]


def test_urdf_gives_the_nominal_laser_pose(tmp_path):
    urdf = _urdf(tmp_path / "robot.urdf")
    params, source = with_nominal_laser_pose(_bag(tmp_path / "bag", []), _params(tmp_path), urdf)
    assert _laser_pose(params) == pytest.approx(EXPECTED, abs=1e-9)
    assert f"nominal laser pose from {urdf} base_link → laser_mount → laser" in source


def test_urdf_wins_over_tf_static_and_the_parameters_file_over_both(tmp_path):
    urdf = _urdf(tmp_path / "robot.urdf")
    bag = _bag(tmp_path / "bag", TREE)  # /tf_static: the laser at (0.2, 0.05), 40°
    params, source = with_nominal_laser_pose(bag, _params(tmp_path), urdf)
    assert _laser_pose(params) == pytest.approx(EXPECTED, abs=1e-9)
    params, source = with_nominal_laser_pose(bag, _params(tmp_path, laser_yaw=0.5), urdf)
    assert _laser_pose(params) == pytest.approx((*EXPECTED[:2], 0.5), abs=1e-9)
    assert f"laser_x, laser_y from {urdf}" in source
    assert "laser_yaw from the parameters file" in source
    params, source = with_nominal_laser_pose(
        bag, _params(tmp_path, laser_x=0.0, laser_y=0.0, laser_yaw=0.0), urdf)
    assert _laser_pose(params) == (0.0, 0.0, 0.0)
    assert source.startswith("nominal laser pose from the parameters file")
    assert f"({urdf} base_link → laser_mount → laser says x = 286.6 mm" in source


def _with(kind=None, rpy=None):
    """JOINTS with the laser mount's joint of another type, or the laser's of another rpy."""
    joints = [list(j) for j in JOINTS]
    if kind:
        joints[1][1] = kind
    if rpy:
        joints[2][5] = rpy
    return [tuple(j) for j in joints]


@pytest.mark.parametrize("write, frame_id, expected", [
    (None, "laser", "URDF not found"),
    (lambda p: p.write_text("this is not xml <"), "laser", "not a URDF (not XML"),
    (lambda p: p.write_text('<package format="3"><name>x</name></package>'), "laser",
     "its root element is <package>, not <robot>"),
    (lambda p: p.write_text('<robot name="r" xmlns:xacro="http://www.ros.org/wiki/xacro">'
                            '<xacro:property name="w" value="1"/><link name="a"/></robot>'),
     "laser", "a xacro file, not a URDF"),
    (lambda p: _urdf(p), "other_laser",
     "no chain of joints from base_link to the scan's frame other_laser; its links: "
     "base_footprint, base_link, laser_mount, laser, left_wheel"),
    (lambda p: _urdf(p, _with(kind="revolute")), "laser",
     "joints that are not fixed: laser_mount_joint (revolute)"),
    (lambda p: _urdf(p, _with(rpy=f"{math.pi} 0 0")), "laser", "mounted upside down"),
], ids=["missing", "not-xml", "not-robot", "xacro", "no-chain", "not-fixed", "upside-down"])
def test_unusable_urdf_is_one_line_and_exit_2(tmp_path, capsys, write, frame_id, expected):
    bag = _bag(tmp_path / "bag", [], frame_id=frame_id)
    (tmp_path / "params.yaml").write_text("sclam:\n  ros__parameters:\n    wheel_base: 0.4\n")
    urdf = tmp_path / "robot.urdf"
    if write:
        write(urdf)
    rc = main(["calibrate", str(bag), "--params", str(tmp_path / "params.yaml"),
               "--urdf", str(urdf), "--quiet"])
    captured = capsys.readouterr()
    assert rc == 2
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("sclam calibrate: error: "), captured.err
    assert expected in lines[0]
    assert "nominal laser pose" not in captured.out  # refused before any other output


def test_calibrate_uses_and_prints_the_urdf_pose(tmp_path, capsys):
    """`sclam calibrate --urdf` on a simulated recording, the parameters file without laser_*:
    the nominal laser pose is the URDF's, and the command says so."""
    sim = tmp_path / "sim"
    truth = simulate(sim, robot="pioneer", duration=20.0, seed=2)
    mount = [truth["laser_x"], truth["laser_y"], truth["laser_yaw"]]
    urdf = _urdf(tmp_path / "robot.urdf", [
        ("base_link_joint", "fixed", "base_footprint", "base_link", "0 0 0.05", "0 0 0"),
        ("laser_joint", "fixed", "base_link", "laser", f"{mount[0]} {mount[1]} 0.3",
         f"0 0 {mount[2]}")])
    rc = main(["calibrate", str(sim), "--params", params_without_laser_pose(sim), "--urdf",
               str(urdf), "--quiet", "--json", str(tmp_path / "c.json")])
    assert rc == 0
    assert f"nominal laser pose from {urdf} base_link → laser" in capsys.readouterr().out
    nominal = json.loads((tmp_path / "c.json").read_text())["nominal"]
    assert [nominal[k] for k in LASER_KEYS] == pytest.approx(mount, abs=1e-9)
