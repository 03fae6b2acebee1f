"""Never crash: each bad input of issue 13, made from a short simulated recording, through
`sclam` as a user runs it. Unusable input: exit status 2, one line
`sclam <command>: error: <reason>` on stderr, nothing written. A bad message inside a good
recording: exit status 0, the message dropped, counted under its reason and warned about.
Never silently wrong: a recording that contradicts its configuration (swapped or backwards
encoders, header stamps on two clocks, scans from two frames) is refused naming the fix, or
repaired and warned about, on stderr and in --json."""
import dataclasses
import json
import math
import os
import shutil
import signal
import sqlite3
import subprocess
import sys
import time
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
from fuzz_cases import spray_mcap

from sclam_ros.cli.main import main
from sclam_ros.core import wiring
from sclam_ros.core.covariance import remaining_step
from sclam_ros.core.estimator import calibrate_keyframes
from sclam_ros.core.inputs import Scan
from sclam_ros.core.params import CALIBRATION_KEYS, SclamParams, atomic_write_text
from sclam_ros.frontend import point_to_line, reference_lines
from sclam_ros.frontend.scan_matching import ScanMatcher
from sclam_ros.io import bag
from sclam_ros.io.messages import stamp_to_sec
from sclam_ros.io.recording import read_recording
from sclam_ros.sim import simulate

SCAN = "sensor_msgs/msg/LaserScan"
JOINT_STATE = "sensor_msgs/msg/JointState"
VENV_BIN = Path(sys.executable).parent
ROS_ENV = dict(os.environ, ROS_DOMAIN_ID=str(100 + os.getpid() % 100),
               RMW_IMPLEMENTATION=os.environ.get("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp"))


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    out = tmp_path_factory.mktemp("good") / "bag"
    simulate(out, robot="pioneer", duration=25.0, seed=2)
    return out


@pytest.fixture(scope="module")
def mcap_recording(tmp_path_factory):
    out = tmp_path_factory.mktemp("good_mcap") / "bag"
    simulate(out, robot="pioneer", duration=25.0, seed=2, storage="mcap")
    return out


def rewrite(src, dst, change_scan=None, change_joint_state=None):
    """Copy the encoder and scan topics of `src` into a new bag `dst` (with its params.yaml),
    each message replaced by change_scan / change_joint_state(number on its topic, message)."""
    with bag.BagWriter(dst) as writer:
        numbers = Counter()
        for topic, t, msg in bag.iter_messages(src, ["/joint_states", "/scan"]):
            change = change_scan if topic == "/scan" else change_joint_state
            if change is not None:
                msg = change(numbers[topic], msg)
            numbers[topic] += 1
            writer.write(topic, SCAN if topic == "/scan" else JOINT_STATE, msg, t)
    shutil.copy(Path(src) / "params.yaml", Path(dst) / "params.yaml")
    return Path(dst)


def calibrate(bag_path, params, tmp_path, *extra):
    out = tmp_path / "calibration.json"
    rc = main(["calibrate", str(bag_path), "--params", str(params), "--json", str(out), "--quiet",
               *extra])
    return rc, out


def assert_one_line_error(capsys, command, *needles):
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith(f"sclam {command}: error: "), err
    assert "Traceback" not in err
    for needle in needles:
        assert needle in lines[0], (needle, lines[0])
    return lines[0]


# --- scans with impossible beam geometry ------------------------------------------------

BAD_GEOMETRY = {  # scan number -> (reason counted, change of the message)
    0: ("scan_non_finite_angles", dict(angle_min=math.nan)),  # even the very first scan
    10: ("scan_non_finite_angles", dict(angle_increment=math.inf)),
    20: ("scan_zero_angle_increment", dict(angle_increment=0.0)),
    # An absurd increment that angle_max agrees with: beams wrap round, points collapse.
    30: ("scan_angles_span_over_a_turn", dict(angle_increment=1e3, angle_max=-math.pi + 359e3)),
    50: ("scan_ranges_angles_mismatch", None),  # 60 more ranges than the angles describe
    # A negative increment with ranges left in order (a mirrored scan) contradicts angle_max.
    60: ("scan_ranges_angles_mismatch", "mirrored"),
}


def break_geometry(number, msg):
    if number not in BAD_GEOMETRY:
        return msg
    change = BAD_GEOMETRY[number][1]
    if change is None:
        return dataclasses.replace(msg, ranges=np.concatenate([msg.ranges, msg.ranges[:60]]))
    if change == "mirrored":
        return dataclasses.replace(msg, angle_increment=-msg.angle_increment)
    return dataclasses.replace(msg, **change)


def test_scans_with_impossible_angles_are_counted_rejections(recording, tmp_path, capsys, caplog):
    bad = rewrite(recording, tmp_path / "bad", break_geometry)
    rc, out = calibrate(bad, bad / "params.yaml", tmp_path)
    assert rc == 0, capsys.readouterr().err
    assert out.is_file()
    warnings = caplog.text
    expected = {}
    for reason, _ in BAD_GEOMETRY.values():
        expected[reason] = expected.get(reason, 0) + 1
    for reason, count in expected.items():
        assert f"rejecting /scan messages (counted): {reason}" in warnings
        assert f"{reason}: {count}" in warnings  # the summary of counted rejections
    assert "Traceback" not in capsys.readouterr().err
    result = json.loads(out.read_text())  # the same counts in --json
    for reason, count in expected.items():
        assert result["rejected"][reason] == count
    scans = result["messages"]["/scan"]
    assert scans["used"] == scans["read"] - len(BAD_GEOMETRY) and scans["corrupt"] == 0
    assert any("rejecting /scan messages (counted): scan_zero_angle_increment" in w
               for w in result["warnings"])


def test_negative_increment_is_the_same_scan(recording, tmp_path, capsys):
    """A scanner listing its beams clockwise (angle_min > angle_max, negative increment)
    describes the same points; the calibration must not change beyond noise."""
    def reverse(number, msg):
        return dataclasses.replace(msg, ranges=msg.ranges[::-1].copy(), angle_min=msg.angle_max,
                                   angle_max=msg.angle_min, angle_increment=-msg.angle_increment)

    reversed_bag = rewrite(recording, tmp_path / "reversed", reverse)
    rc, out = calibrate(recording, recording / "params.yaml", tmp_path / "a")
    assert rc == 0
    rc, out_reversed = calibrate(reversed_bag, reversed_bag / "params.yaml", tmp_path / "b")
    assert rc == 0
    a, b = json.loads(out.read_text()), json.loads(out_reversed.read_text())
    assert a["scans_used"] == b["scans_used"]
    for key, sigma in a["sigma"].items():
        assert abs(a[key] - b[key]) < 0.5 * sigma, key


def test_matches_without_lines_are_counted_not_used():
    """Outdoors, no walls: the reference scan has no points on lines, ReferenceScan is None.
    KISS-ICP still matches, but nothing confirms its answer: the match is counted as not
    used (z None) instead of crashing or entering the graph unverified."""
    rng = np.random.default_rng(3)
    trees = rng.uniform(-8, 8, (400, 2))  # scattered poles: no two neighbourhoods on a line
    matcher = point_to_line.RefinedScanMatcher(ScanMatcher())
    matches = 0
    for i in range(8):
        points = np.column_stack([trees - [0.03 * i, 0.0], np.zeros(len(trees))])  # laser frame
        scan = Scan(stamp=0.1 * i, ranges=np.hypot(points[:, 0], points[:, 1]), angle_min=-np.pi,
                    angle_increment=2 * np.pi / len(trees), range_min=0.0, range_max=30.0)
        match, z, _ = matcher.add_scan(scan, np.array([0.03, 0.0, 0.0]), points)
        matches += match is not None
        assert z is None
    assert reference_lines.ReferenceScan.from_points(points) is None
    assert matches > 1 and matcher.matches == matches
    assert matcher.unrefined["no_lines"] == matches


def test_recording_whose_matches_are_all_unconfirmed_says_why(recording):
    """When no scan match survives the point-to-line check (scans without walls), the error
    says so instead of only "0 laser edges"."""
    from sclam_ros.core.estimator import CalibrationError

    params = SclamParams.from_yaml(recording / "params.yaml")
    rec = read_recording(recording, params)
    keyframes = [dataclasses.replace(kf, laser_from=None, laser_motion=None, laser_information=None)
                 for kf in rec.keyframes]
    rec.rejections.add("match_unconfirmed", sum(kf.laser_motion is not None for kf in rec.keyframes))
    with pytest.raises(CalibrationError, match="too little straight structure"):
        calibrate_keyframes(keyframes, params, rec.rejections)


# --- a topic of the wrong type ---------------------------------------------------------


@pytest.mark.parametrize("key", ["scan_topic", "joint_states_topic"])
def test_topic_of_another_type_is_a_clear_error(recording, tmp_path, capsys, key):
    params = tmp_path / "p.yaml"
    text = (recording / "params.yaml").read_text()
    old = "/scan" if key == "scan_topic" else "/joint_states"
    params.write_text(text.replace(f"{key}: {old}", f"{key}: /ground_truth/odom"))
    rc, out = calibrate(recording, params, tmp_path)
    assert rc == 2
    assert_one_line_error(capsys, "calibrate", key, "/ground_truth/odom", "nav_msgs/msg/Odometry")
    assert not out.exists()


# --- parameters files that are not parameters --------------------------------------------


def _params_cases(recording, tmp_path):
    good = (recording / "params.yaml").read_text()
    (tmp_path / "folder").mkdir()
    binary = tmp_path / "binary.yaml"
    binary.write_bytes(next(recording.glob("*.db3")).read_bytes()[:4096])
    cases = {
        "folder": (tmp_path / "folder", ["is a folder"]),
        "binary": (binary, ["not a text file"]),
        "not_yaml": ("sclam:\n  ros__parameters: [unclosed\n", ["not valid YAML", "line"]),
        "empty": ("", ["empty"]),
        "unknown_key": (good.replace("wheel_base:", "wheel_bas:"),
                        ["unknown parameter", "wheel_bas (wheel_base?)"]),
        "huge_radius": (good.replace("wheel_radius_left: ", "wheel_radius_left: 1.0e+300 #"),
                        ["wheel_radius_left must be a number in (0, 5]"]),
        "negative_base": (good.replace("wheel_base: ", "wheel_base: -0.3 #"),
                          ["wheel_base must be a number in (0, 20]"]),
    }
    for name, (content, _) in list(cases.items()):
        if isinstance(content, str):
            path = tmp_path / f"{name}.yaml"
            path.write_text(content)
            cases[name] = (path, cases[name][1])
    return cases


PARAMS_CASES = ["folder", "binary", "not_yaml", "empty", "unknown_key", "huge_radius",
                "negative_base"]


@pytest.mark.parametrize("track", [False, True], ids=["batch", "track"])
@pytest.mark.parametrize("case", PARAMS_CASES)
def test_unusable_parameters_file_is_one_line_and_exit_2(recording, tmp_path, capsys, case, track):
    path, needles = _params_cases(recording, tmp_path)[case]
    extra = ["--track", str(tmp_path / "track.csv")] if track else []
    rc, out = calibrate(recording, path, tmp_path, *extra)
    assert rc == 2
    assert_one_line_error(capsys, "calibrate", *needles)
    assert not out.exists() and not (tmp_path / "track.csv").exists()


# --- corrupt storage -------------------------------------------------------------------


def _read_counts(path):
    counts = bag.ReadCounts()
    for _ in bag.iter_messages(path, ["/scan", "/joint_states"], counts=counts):
        pass
    return counts


def test_corrupt_db3_messages_are_skipped_counted_and_the_rest_used(recording, tmp_path, capsys,
                                                                   caplog):
    broken = tmp_path / "broken"
    shutil.copytree(recording, broken)
    db = sqlite3.connect(next(broken.glob("*.db3")))
    ids = {name: [row[0] for row in db.execute(
        "SELECT m.id FROM messages m JOIN topics t ON m.topic_id = t.id WHERE t.name = ? "
        "ORDER BY m.timestamp", (name,))] for name in ("/scan", "/joint_states")}
    db.execute("UPDATE messages SET data = substr(data, 1, 20) WHERE id = ?", (ids["/scan"][50],))
    db.execute("UPDATE messages SET data = randomblob(length(data)) WHERE id = ?",
               (ids["/joint_states"][300],))
    db.commit()
    db.close()

    counts = _read_counts(broken).as_dict()
    for topic in ("/scan", "/joint_states"):
        assert counts[topic] == {"read": len(ids[topic]) - 1, "used": 0, "corrupt": 1}

    caplog.clear()
    rc, out = calibrate(broken, broken / "params.yaml", tmp_path)
    assert rc == 0 and out.is_file()
    assert "corrupt /scan message" in caplog.text and "corrupt /joint_states message" in caplog.text
    assert "Traceback" not in capsys.readouterr().err


def _dropped(counts, info):
    return any(counts.read[t] + counts.corrupt[t] < info[t][1] for t in ("/scan", "/joint_states"))


# Where random bytes land decides what breaks: mostly range values (undetectable: mcap's
# CRCs are not checked by rosbags), sometimes a record length (rosbags' reader raises
# OverflowError or drops the rest of a chunk). Each case sprays 200 bytes at seeded places
# in its region until the named symptom shows; about one in four places does.
MCAP_CASES = {
    "near_end_storage_error": (0.96, lambda counts, info: counts.unreadable > 0),
    "middle_silent_drop": (0.5, lambda counts, info: not counts.unreadable and _dropped(counts, info)),
}


@pytest.mark.parametrize("case", sorted(MCAP_CASES))
def test_random_bytes_in_mcap_lose_only_their_part_and_say_so(mcap_recording, tmp_path, capsys,
                                                              caplog, case):
    region, symptom = MCAP_CASES[case]
    info = bag.topic_info(mcap_recording)
    broken = tmp_path / "broken"
    spray_mcap(mcap_recording, broken, region, symptom, ["/scan", "/joint_states"])
    caplog.clear()
    counts = _read_counts(broken)  # again, for its warnings
    if counts.unreadable:
        assert "storage unreadable" in caplog.text
    for topic in ("/scan", "/joint_states"):
        found = counts.read[topic] + counts.corrupt[topic]
        if found < info[topic][1]:  # what the reader dropped is warned, with both numbers
            assert (f"topic {topic}: the metadata announces {info[topic][1]} messages, the "
                    f"reader returned {found}") in caplog.text

    caplog.clear()
    rc, out = calibrate(broken, broken / "params.yaml", tmp_path)
    assert rc == 0 and out.is_file()
    assert "the metadata announces" in caplog.text
    assert "Traceback" not in capsys.readouterr().err


# --- sclam play -------------------------------------------------------------------------


def test_play_missing_or_corrupt_bag_is_one_line(tmp_path, recording, capsys):
    assert main(["play", str(tmp_path / "nope")]) == 2
    assert_one_line_error(capsys, "play", "nope")
    broken = tmp_path / "broken"
    shutil.copytree(recording, broken)
    db3 = next(broken.glob("*.db3"))
    db3.write_bytes(b"not a database" * 100)
    assert main(["play", str(broken)]) == 2
    assert_one_line_error(capsys, "play", "cannot open bag")


def _catches(pid, signum) -> bool:
    """True once process `pid` has a handler installed for `signum` (Linux /proc)."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("SigCgt:"):
            return bool(int(line.split()[1], 16) >> (signum - 1) & 1)
    return False


def test_play_ends_cleanly_on_sigterm(recording, tmp_path):
    pytest.importorskip("rclpy")
    process = subprocess.Popen([str(VENV_BIN / "sclam"), "play", str(recording)], cwd=tmp_path,
                               env=ROS_ENV, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        deadline = time.monotonic() + 60
        while not _catches(process.pid, signal.SIGTERM):
            assert process.poll() is None and time.monotonic() < deadline, "play never started"
            time.sleep(0.05)
        process.send_signal(signal.SIGTERM)
        code = process.wait(30)
    finally:
        if process.poll() is None:
            process.kill()
    output = process.stdout.read()
    assert code == 0, output
    assert "Traceback" not in output and "sclam play: published" in output


# --- silently wrong: the recording contradicts the configuration --------------------------


@pytest.fixture(scope="module")
def good(recording, tmp_path_factory):
    """--json of the unchanged recording, to compare the repaired cases with."""
    rc, out = calibrate(recording, recording / "params.yaml", tmp_path_factory.mktemp("good_json"))
    assert rc == 0
    return json.loads(out.read_text())


def test_json_says_converged_observable_warnings_rejected_and_messages(recording, good):
    assert good["converged"] is True
    assert set(good["observable"]) == set(CALIBRATION_KEYS)
    assert all(isinstance(value, bool) for value in good["observable"].values())
    assert isinstance(good["warnings"], list) and isinstance(good["rejected"], dict)
    info = bag.topic_info(recording)
    for topic in ("/joint_states", "/scan"):
        counts = good["messages"][topic]
        assert counts["read"] == info[topic][1] and counts["corrupt"] == 0
        assert counts["used"] == counts["read"]


def test_converged_means_a_further_step_moves_no_parameter(recording):
    """The criterion behind "converged": at the solution a Gauss-Newton step moves nothing
    by 0.1σ; from a calibration 3σ off it does (so the step measures what is left)."""
    params = SclamParams.from_yaml(recording / "params.yaml")
    result = calibrate_keyframes(read_recording(recording, params).keyframes, params)
    sigma = np.array([result.sigma[k] for k in CALIBRATION_KEYS])
    problem, blocks = result.problem, ["odometry", "laser"]
    step, _ = remaining_step(problem, problem.values, blocks)
    assert np.all(np.abs(step) < 0.1 * sigma), step / sigma
    moved = problem.values.copy()
    moved["odometry"] = moved["odometry"] + 3.0 * sigma[:3]
    step, _ = remaining_step(problem, moved, blocks)
    assert np.max(np.abs(step[:3]) / sigma[:3]) > 1.0, step / sigma


def swap_joint_names(number, msg):
    return dataclasses.replace(msg, name=list(reversed(msg.name)))


def negate(*joints):
    def change(number, msg):
        position = np.array(msg.position, float)
        position[[msg.name.index(j) for j in joints]] *= -1.0
        return dataclasses.replace(msg, position=position)
    return change


WIRING_CASES = {  # change of the JointState messages -> (what is said, the fix named)
    "swapped": (swap_joint_names, "the left and right wheel joints are swapped",
                {"left_wheel_joint": "right_wheel_joint", "right_wheel_joint": "left_wheel_joint"}),
    "left_backwards": (negate("left_wheel_joint"),
                       "the left wheel's encoder (left_wheel_joint) counts backwards",
                       {"left_encoder_sign": -1}),
    "both_backwards": (negate("left_wheel_joint", "right_wheel_joint"),
                       "the left wheel's encoder (left_wheel_joint) counts backwards and the "
                       "right wheel's encoder (right_wheel_joint) counts backwards",
                       {"left_encoder_sign": -1, "right_encoder_sign": -1}),
}


@pytest.mark.parametrize("case", sorted(WIRING_CASES))
def test_swapped_or_backwards_encoders_are_refused_with_the_fix(recording, tmp_path, capsys, case):
    change, said, fix = WIRING_CASES[case]
    bad = rewrite(recording, tmp_path / case, change_joint_state=change)
    rc, out = calibrate(bad, bad / "params.yaml", tmp_path)
    assert rc == 2 and not out.exists()
    fix_text = "set " + ", ".join(f"{k}: {v}" for k, v in fix.items())
    line = assert_one_line_error(capsys, "calibrate", "contradict the laser", said, fix_text)
    assert "; or " not in line  # a drive with turns and straights leaves one explanation
    # With the parameters it names, the same recording calibrates to the truth.
    fixed = dataclasses.replace(SclamParams.from_yaml(bad / "params.yaml"), **fix)
    fixed.write_yaml(tmp_path / "fixed.yaml")
    rc, out = calibrate(bad, tmp_path / "fixed.yaml", tmp_path)
    assert rc == 0, capsys.readouterr().err
    result, truth = json.loads(out.read_text()), json.loads((recording / "truth.json").read_text())
    for key in CALIBRATION_KEYS:
        assert abs(result[key] - truth[key]) < 4 * result["sigma"][key], key


def test_the_named_fix_undoes_each_wiring(recording):
    """Every signed permutation of the two wheels, applied to the encoder increments of a
    good recording: named, and the parameters named read the wheels right again."""
    params = SclamParams.from_yaml(recording / "params.yaml")
    keyframes = read_recording(recording, params).keyframes
    assert wiring.wiring_problem(keyframes, params) is None
    for matrix in list(wiring._wirings())[1:]:  # the first is the identity
        miswired = [dataclasses.replace(kf, dphi=None if kf.dphi is None else matrix @ kf.dphi)
                    for kf in keyframes]
        reason = wiring.wiring_problem(miswired, params)
        assert reason is not None and "; or " not in reason, matrix
        settings = reason.split(": set ")[1].split(" (")[0]
        fix = dict(item.split(": ") for item in settings.split(", "))
        fixed = dataclasses.replace(params, **{k: float(v) if "sign" in k else v
                                               for k, v in fix.items()})
        slots = {params.left_wheel_joint: 0, params.right_wheel_joint: 1}
        for kf, bad in zip(keyframes, miswired):
            if kf.dphi is not None:  # what the fixed parameters read from the same slots
                read = [fixed.left_encoder_sign * bad.dphi[slots[fixed.left_wheel_joint]],
                        fixed.right_encoder_sign * bad.dphi[slots[fixed.right_wheel_joint]]]
                assert np.allclose(read, kf.dphi), (matrix, reason)


def shift_header(offset):
    def change(number, msg):
        stamp = bag.time_msg(stamp_to_sec(msg.header.stamp) + offset)
        return dataclasses.replace(msg, header=dataclasses.replace(msg.header, stamp=stamp))
    return change


@pytest.mark.parametrize("topic,offset", [("/joint_states", 3.0), ("/scan", -5.0)])
def test_header_stamps_of_another_clock_are_moved_onto_one(recording, good, tmp_path, caplog,
                                                            topic, offset):
    key = "change_scan" if topic == "/scan" else "change_joint_state"
    bad = rewrite(recording, tmp_path / "bad", **{key: shift_header(offset)})
    rc, out = calibrate(bad, bad / "params.yaml", tmp_path)
    assert rc == 0
    result = json.loads(out.read_text())
    said = f"{topic} header stamps are {offset:+.3f} s off their record stamps"
    assert any(said in w for w in result["warnings"]), result["warnings"]
    assert said in caplog.text
    for key in CALIBRATION_KEYS:  # one time base: the calibration of the unshifted recording
        assert abs(result[key] - good[key]) < 0.1 * good["sigma"][key], key


def test_scans_of_another_frame_are_a_warning_on_stderr_and_in_json(recording, tmp_path):
    def relabel(number, msg):
        if number < 150:
            return msg
        return dataclasses.replace(msg, header=dataclasses.replace(msg.header, frame_id="laser_2"))

    bad = rewrite(recording, tmp_path / "bad", change_scan=relabel)
    out = tmp_path / "calibration.json"
    proc = subprocess.run([str(VENV_BIN / "sclam"), "calibrate", str(bad), "--params",
                           str(bad / "params.yaml"), "--json", str(out), "--quiet"],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    warnings = json.loads(out.read_text())["warnings"]
    assert any("frame_id changes" in w and "laser: 150 scans" in w and "laser_2" in w
               for w in warnings), warnings
    stderr = [line for line in proc.stderr.splitlines() if "warning" in line]
    assert all(line.startswith("sclam calibrate: warning: ") for line in stderr), proc.stderr
    assert [line[len("sclam calibrate: warning: "):] for line in stderr] == warnings


# --- sclam_node's command line ------------------------------------------------------------


def _node(tmp_path, *args):
    return subprocess.run([str(VENV_BIN / "sclam_node"), *args], cwd=tmp_path,
                          env=ROS_ENV, capture_output=True, text=True,
                          timeout=60)


def test_node_help_prints_usage_and_starts_nothing(tmp_path):
    pytest.importorskip("rclpy")
    proc = _node(tmp_path, "--help")
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.startswith("usage: sclam_node") and "wheel_radius_left" in proc.stdout
    assert "calibrating from" not in proc.stdout + proc.stderr  # the node never started


def test_node_with_broken_yaml_is_one_line_and_exit_2(tmp_path):
    pytest.importorskip("rclpy")
    broken = tmp_path / "broken.yaml"
    broken.write_text("sclam:\n  ros__parameters: [unclosed\n")
    proc = _node(tmp_path, "--ros-args", "--params-file", str(broken))
    assert proc.returncode == 2, proc.stdout + proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("sclam_node: error: "), proc.stderr
    assert "not valid YAML" in lines[0] and "broken.yaml" in lines[0]


def test_node_warns_unknown_parameters_by_name(recording, tmp_path):
    pytest.importorskip("rclpy")
    params = tmp_path / "params.yaml"
    params.write_text((recording / "params.yaml").read_text().replace(
        "ros__parameters:", "ros__parameters:\n    wheel_bas: 0.4\n    laser_frame: laser"))
    log = tmp_path / "node.log"
    with open(log, "w") as out:
        process = subprocess.Popen([str(VENV_BIN / "sclam_node"), "--ros-args", "--params-file",
                                    str(params)], cwd=tmp_path, env=ROS_ENV,
                                   stdout=out, stderr=subprocess.STDOUT, text=True)
    try:
        deadline = time.monotonic() + 60
        while "calibrating from" not in log.read_text():
            assert process.poll() is None and time.monotonic() < deadline, log.read_text()
            time.sleep(0.05)
    finally:
        process.kill()  # what is tested was said at start-up
        process.wait()
    text = log.read_text()
    said = "unknown parameter(s) ignored: laser_frame (base_frame?), wheel_bas (wheel_base?)"
    assert said in text, text
    assert "Traceback" not in text


# --- saving ---------------------------------------------------------------------------------


def test_a_killed_save_leaves_the_old_file_and_the_next_save_no_temporary_file(tmp_path):
    """SIGKILL while atomic_write_text writes (no `finally` runs): the old file stays whole,
    and the next save removes the temporary file the killed one left."""
    target = tmp_path / "calibration.yaml"
    target.write_text("old\n")
    writer = ("import sys; from sclam_ros.core.params import atomic_write_text; "
              "atomic_write_text(sys.argv[1], 'x' * 100_000_000)")
    for _ in range(5):  # the kill must land while the temporary file exists
        process = subprocess.Popen([sys.executable, "-c", writer, str(target)])
        deadline = time.monotonic() + 60
        while not list(tmp_path.glob(".calibration.yaml.*.tmp")) and process.poll() is None:
            assert time.monotonic() < deadline
            time.sleep(0.001)
        process.kill()
        process.wait()
        if list(tmp_path.glob(".calibration.yaml.*.tmp")):
            break
    else:
        pytest.fail("the writer was never caught writing")
    assert target.read_text() == "old\n"
    atomic_write_text(target, "new\n")
    assert target.read_text() == "new\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["calibration.yaml"]
