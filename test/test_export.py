"""Exports a robot loads (URDF joint, diff_drive_controller block, params YAML) and TUM
trajectories evo reads; every `sclam` command's --help."""
import json
import math
import xml.etree.ElementTree as ET

import numpy as np
import pytest
import yaml

from sclam_ros.cli.main import COMMANDS, main
from sclam_ros.core.params import CALIBRATION_KEYS, SclamParams
from sclam_ros.io.export import tum_text, trajectory_paths
from sclam_ros.io.recording import read_ground_truth
from sclam_ros.sim import simulate

CALIBRATION = {"wheel_radius_left": 0.1262, "wheel_radius_right": 0.1274, "wheel_base": 0.5831,
               "laser_x": 0.2271, "laser_y": 0.0123, "laser_yaw": 0.0421}
NOMINAL = {"wheel_radius_left": 0.125, "wheel_radius_right": 0.125, "wheel_base": 0.56,
           "laser_x": 0.22, "laser_y": 0.0, "laser_yaw": 0.0}


@pytest.fixture
def params_file(tmp_path):
    path = tmp_path / "params.yaml"
    SclamParams(**NOMINAL, base_frame="base_footprint").write_yaml(path)
    return path


def _calibration_file(tmp_path, unobservable=(), frames=True):
    doc = dict(CALIBRATION, sigma={k: 1e-3 for k in CALIBRATION_KEYS}, nominal=NOMINAL,
               observable={k: k not in unobservable for k in CALIBRATION_KEYS})
    if frames:
        doc["frames"] = {"base": "base_footprint", "laser": "lidar_link"}
    path = tmp_path / "calibration.json"
    path.write_text(json.dumps(doc))
    return path


def _export(capsys, *args):
    assert main(["export", *map(str, args)]) == 0
    return capsys.readouterr().out


def test_urdf_joint_places_the_laser_where_the_calibration_says(tmp_path, capsys):
    """The exported joint, put in a minimal robot, loads with yourdfpy (the URDF library
    `sclam calibrate --urdf` reads with) and puts the laser at the calibrated pose."""
    yourdfpy = pytest.importorskip("yourdfpy")
    text = _export(capsys, _calibration_file(tmp_path), "--format", "urdf")
    urdf = tmp_path / "robot.urdf"
    urdf.write_text(f'<robot name="robot"><link name="base_footprint"/><link name="lidar_link"/>'
                    f"{text}</robot>")
    robot = yourdfpy.URDF.load(str(urdf), load_meshes=False)
    (joint,) = robot.robot.joints
    assert (joint.type, joint.parent, joint.child) == ("fixed", "base_footprint", "lidar_link")
    placed = robot.get_transform("lidar_link", "base_footprint")  # base ← laser
    assert placed[:2, 3] == pytest.approx([CALIBRATION["laser_x"], CALIBRATION["laser_y"]],
                                          abs=1e-6)
    assert math.atan2(placed[1, 0], placed[0, 0]) == pytest.approx(CALIBRATION["laser_yaw"],
                                                                   abs=1e-6)
    assert placed[2, 2] == pytest.approx(1.0)  # level: no roll or pitch


def test_unobservable_parameter_keeps_its_nominal_value_and_is_named(tmp_path, capsys, params_file):
    calibration = _calibration_file(tmp_path, unobservable=("laser_y", "wheel_base"))
    urdf = _export(capsys, calibration, "--format", "urdf")
    origin = ET.fromstring(urdf[urdf.index("<joint"):]).find("origin")
    assert float(origin.get("xyz").split()[1]) == NOMINAL["laser_y"]
    assert "NOT OBSERVABLE" in urdf and "laser_y" in urdf
    drive = _export(capsys, calibration, "--format", "diff-drive")
    assert yaml.safe_load(drive)["diff_drive_controller"]["ros__parameters"][
        "wheel_separation"] == pytest.approx(NOMINAL["wheel_base"])
    assert "wheel_base" in drive.split("diff_drive_controller:")[0]  # named in the comment
    out = tmp_path / "params.out.yaml"
    _export(capsys, calibration, "--format", "params", "--params", params_file, "--out", out)
    assert SclamParams.from_yaml(out).laser_y == NOMINAL["laser_y"]
    assert "laser_y" in out.read_text().split("sclam:")[0]


def test_diff_drive_block_reproduces_the_wheel_radii(tmp_path, capsys):
    text = _export(capsys, _calibration_file(tmp_path), "--format", "diff-drive",
                   "--controller", "base_controller")
    block = yaml.safe_load(text)["base_controller"]["ros__parameters"]
    # Doubles, as the controller declares them (ROS 2 refuses an integer for a double).
    assert all(isinstance(value, float) for value in block.values())
    # The fields diff_drive_controller reads for its wheel geometry.
    assert set(block) == {"wheel_separation", "wheel_separation_multiplier", "wheel_radius",
                          "left_wheel_radius_multiplier", "right_wheel_radius_multiplier"}
    # The controller's radius of each side: wheel_radius × that side's multiplier.
    assert block["wheel_radius"] * block["left_wheel_radius_multiplier"] == pytest.approx(
        CALIBRATION["wheel_radius_left"], rel=1e-8)
    assert block["wheel_radius"] * block["right_wheel_radius_multiplier"] == pytest.approx(
        CALIBRATION["wheel_radius_right"], rel=1e-8)
    assert block["wheel_separation"] * block["wheel_separation_multiplier"] == pytest.approx(
        CALIBRATION["wheel_base"], rel=1e-8)


def test_params_export_round_trips(tmp_path, capsys, params_file):
    out = tmp_path / "calibrated.yaml"
    _export(capsys, _calibration_file(tmp_path), "--format", "params", "--params", params_file,
            "--out", out)
    params = SclamParams.from_yaml(out)
    assert params.calibration() == pytest.approx(CALIBRATION)
    assert params.base_frame == "base_footprint"  # everything else as in the input


def test_export_refuses_what_it_cannot_use(tmp_path, capsys, params_file):
    calibration = _calibration_file(tmp_path)
    assert main(["export", str(calibration), "--format", "params"]) == 2  # no --params
    assert "--params" in capsys.readouterr().err
    (tmp_path / "bad.json").write_text("{\"wheel_base\": 1}")
    assert main(["export", str(tmp_path / "bad.json"), "--format", "urdf"]) == 2
    assert "not a calibration" in capsys.readouterr().err


def test_frames_default_to_the_params_base_frame(tmp_path, capsys, params_file):
    calibration = _calibration_file(tmp_path, frames=False)
    joint = _export(capsys, calibration, "--format", "urdf", "--params", params_file)
    assert '<parent link="base_footprint"/>' in joint and '<child link="laser"/>' in joint


def test_tum_lines_follow_the_format():
    text = tum_text([1.5, 2.0], np.array([[1.0, 2.0, 0.0], [3.0, -1.0, math.pi / 2]]))
    rows = np.array([[float(v) for v in line.split()] for line in text.splitlines()])
    assert rows.shape == (2, 8)  # timestamp x y z qx qy qz qw
    assert rows[1] == pytest.approx([2.0, 3.0, -1.0, 0, 0, 0, math.sqrt(0.5), math.sqrt(0.5)])


# --- end to end on a simulated recording --------------------------------------------


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory):
    out = tmp_path_factory.mktemp("export")
    bag = out / "bag"
    simulate(bag, robot="powerbot", duration=60.0, seed=5)
    trajectory = out / "run.tum"
    rc = main(["calibrate", str(bag), "--params", str(bag / "params.yaml"), "--quiet",
               "--json", str(out / "calibration.json"), "--trajectory", str(trajectory)])
    assert rc == 0
    return bag, out / "calibration.json", trajectory


def test_calibration_json_names_the_frames(calibrated):
    bag, calibration, _ = calibrated
    frames = json.loads(calibration.read_text())["frames"]
    assert frames == {"base": "base_link", "laser": "laser"}  # the simulator's scan frame_id


def test_trajectories_load_in_evo(calibrated):
    file_interface = pytest.importorskip("evo.tools.file_interface")
    _, _, trajectory = calibrated
    paths = trajectory_paths(trajectory)
    lengths = set()
    for name in ("optimised", "nominal", "calibrated", "truth"):
        traj = file_interface.read_tum_trajectory_file(str(paths[name]))
        lengths.add(traj.num_poses)
        assert traj.num_poses > 100, name
    assert len(lengths) == 1  # the same stamps, pose for pose


def _tum_poses(path):
    rows = np.loadtxt(path)
    return rows[:, 0], rows[:, 1:3], 2 * np.arctan2(rows[:, 6], rows[:, 7])


def _position_errors(path, truth):
    """Position errors against the ground truth, both started at the first pose."""
    t, xy, _ = _tum_poses(path)
    t_true, poses = truth
    true_xy = np.column_stack([np.interp(t, t_true, poses[:, i]) for i in (0, 1)])
    theta0 = np.interp(t[0], t_true, np.unwrap(poses[:, 2]))
    c, s = math.cos(theta0), math.sin(theta0)
    relative = (true_xy - true_xy[0]) @ np.array([[c, -s], [s, c]])  # into the first pose's frame
    return np.linalg.norm(xy - relative, axis=1)


def test_calibrated_odometry_is_closer_to_the_truth_than_nominal(calibrated):
    bag, _, trajectory = calibrated
    truth = read_ground_truth(bag)
    paths = trajectory_paths(trajectory)
    nominal = _position_errors(paths["nominal"], truth)
    corrected = _position_errors(paths["calibrated"], truth)
    assert corrected[-1] < 0.5 * nominal[-1]
    assert np.sqrt(np.mean(corrected**2)) < 0.5 * np.sqrt(np.mean(nominal**2))


@pytest.mark.parametrize("command", ["", *sorted(COMMANDS), "fleet report"])
def test_every_command_prints_its_help(command, capsys):
    """`sclam --help` and `sclam COMMAND --help` exit 0 (sclam_node --help: test_robustness)."""
    with pytest.raises(SystemExit) as exit_:
        main([*command.split(), "--help"])
    assert exit_.value.code == 0
    out = capsys.readouterr().out
    if command:
        assert out.startswith(f"usage: sclam {command.split()[0]}")
    else:  # every command listed
        assert out.startswith("usage: sclam") and all(name in out for name in COMMANDS)
