"""`sclam convert` on the real logs in ../shared/data (skipped when absent); writes only
into tmp_path."""
from pathlib import Path

import numpy as np
import pytest

from sclam_ros.io import bag
from sclam_ros.cli import main as cli
from sclam_ros.core import kinematics, se2
from sclam_ros.io.convert import (
    OPTIODOM_TICKS_PER_REV,
    URG_BEAMS,
    ConvertError,
    convert_optiodom,
    read_optiodom,
)
from sclam_ros.core.params import SclamParams

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"
MINES = DATA / "breezyslam-mines" / "exp1.dat"
OPTIODOM = DATA / "optiodom-diff"

needs = pytest.mark.skipif(not DATA.is_dir(), reason=f"{DATA} not present")


def _runs(shape):
    return sorted((OPTIODOM / shape).glob("*/*_run-??.csv"))


def _path_length(poses):
    return float(np.sum(np.linalg.norm(np.diff(poses[:, :2], axis=0), axis=1)))


def _read(bag_path, topic):
    return [(stamp, msg) for _, stamp, msg in bag.iter_messages(bag_path, [topic])]


@needs
def test_breezyslam_bag_scans_ticks_params_attribution(tmp_path):
    out = tmp_path / "mines"
    assert cli.main(["convert", "breezyslam", str(MINES), str(out)]) == 0
    scans = _read(out / "bag", "/scan")
    joints = _read(out / "bag", "/joint_states")
    assert len(scans) == len(joints) == 756  # README: 756 scans
    scan = scans[0][1]
    assert scan.header.frame_id == "laser" and len(scan.ranges) == URG_BEAMS
    assert scan.angle_min == pytest.approx(np.radians(-120), abs=1e-6)
    assert scan.angle_max == pytest.approx(np.radians(120), abs=1e-6)
    assert scan.angle_increment > 0  # counter-clockwise, index 0 on the right
    all_ranges = np.concatenate([s.ranges for _, s in scans])
    # ~54 % of beams have no return (0 mm in the log) and become inf.
    assert 0.4 < np.mean(np.isinf(all_ranges)) < 0.7
    finite = all_ranges[np.isfinite(all_ranges)]
    assert finite.min() > 0 and finite.max() < 10.0
    positions = np.array([m.position for _, m in joints])
    assert list(joints[0][1].name) == ["left_wheel_joint", "right_wheel_joint"]
    # Dead reckoning with the nominal parameters: about 46 m of path (README).
    params = SclamParams.from_yaml(out / "params.yaml")
    assert params.ticks_per_revolution == 2000 and params.laser_x == pytest.approx(0.145)
    dphi = np.diff(positions, axis=0) * 2 * np.pi / params.ticks_per_revolution
    k = params.calibration_vector()[:3]
    length = float(np.sum(np.abs(kinematics.arc_length_and_rotation(dphi, k)[0])))
    assert length == pytest.approx(46.0, rel=0.1)
    text = (out / "ATTRIBUTION.md").read_text()
    assert "simondlevy/BreezySLAM" in text and "1170285cd42a" in text and "LGPL-3.0" in text
    assert (out / "SOURCE_LICENSE.md").is_file()


@needs
def test_breezyslam_scan_delay_stamps_scans_earlier_and_leaves_the_ticks(tmp_path):
    raw = np.loadtxt(MINES)
    assert cli.main(["convert", "breezyslam", str(MINES), str(tmp_path / "late"),
                     "--scan-delay", "0.15"]) == 0
    stamp = lambda m: m.header.stamp.sec + m.header.stamp.nanosec * 1e-9
    scans = _read(tmp_path / "late" / "bag", "/scan")
    joints = _read(tmp_path / "late" / "bag", "/joint_states")
    assert len(scans) == len(joints) == len(raw)
    # The scan is stamped when it was taken, and recorded when its log line was written.
    assert np.allclose([stamp(m) for _, m in scans], raw[:, 0] * 1e-6 - 0.15, atol=1e-6)
    assert np.allclose([t for t, _ in scans], raw[:, 0] * 1e-6, atol=1e-6)
    assert np.allclose([stamp(m) for _, m in joints], raw[:, 0] * 1e-6, atol=1e-6)
    assert np.array_equal([m.position for _, m in joints], raw[:, [2, 3]])
    assert "150 ms before" in (tmp_path / "late" / "ATTRIBUTION.md").read_text()


def _dead_reckoning(ticks, params):
    dphi = np.diff(ticks, axis=0) * 2 * np.pi / params.ticks_per_revolution
    k = params.calibration_vector()[:3]
    poses = [np.zeros(3)]
    for motion in kinematics.forward(dphi, k):
        poses.append(se2.compose(poses[-1], motion))
    return np.array(poses)


@needs
@pytest.mark.parametrize("shape", ["circular", "square"])
def test_optiodom_ticks_integrate_to_the_mocap_path_length(tmp_path, shape):
    src = _runs(shape)[0]
    out = tmp_path / shape
    assert cli.main(["convert", "optiodom", str(src), str(out)]) == 0
    params = SclamParams.from_yaml(out / "params.yaml")
    assert params.ticks_per_revolution == pytest.approx(43.7 * 64)
    joints = _read(out / "bag", "/joint_states")
    mocap = _read(out / "bag", "/mocap/odom")
    assert len(joints) == len(mocap) > 1000
    ticks = np.array([m.position for _, m in joints])
    truth = np.array([[m.pose.pose.position.x, m.pose.pose.position.y] for _, m in mocap])
    odo = _dead_reckoning(ticks, params)
    ratio = _path_length(odo) / _path_length(truth)
    assert ratio == pytest.approx(1.0, abs=0.1), ratio
    # Left/right are not swapped: the heading turns the way the mocap's does.
    _, _, th_truth = read_optiodom(src)[1].T
    total_turn_truth = np.sum(se2.wrap_angle(np.diff(th_truth)))
    turned = np.sum(se2.wrap_angle(np.diff(odo[:, 2])))
    assert turned == pytest.approx(total_turn_truth, rel=0.15), (turned, total_turn_truth)
    text = (out / "ATTRIBUTION.md").read_text()
    assert "sousarbarb/optiodom" in text and "8e025fd7" in text and "MIT" in text


@needs
def test_quadrature_factor_would_be_far_off():
    # The ×4 alternative (43.7·64·4 ticks/rev) would make the path 4× too short.
    src = _runs("square")[0]
    _, truth, ticks = read_optiodom(src)
    params = SclamParams(ticks_per_revolution=4 * OPTIODOM_TICKS_PER_REV,
                         wheel_radius_left=0.042, wheel_radius_right=0.042, wheel_base=0.2)
    assert _path_length(_dead_reckoning(ticks, params)) < 0.4 * _path_length(truth)


def test_bad_source_is_a_clear_error(tmp_path):
    bad = tmp_path / "bad.csv"
    bad.write_text("1,2,3\n4,5,6\n")
    with pytest.raises(ConvertError, match="6 columns"):
        convert_optiodom(bad, tmp_path / "out")
    assert cli.main(["convert", "optiodom", str(bad), str(tmp_path / "out2")]) == 2
