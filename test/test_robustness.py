"""Never crash: each bad input of issue 13, made from a short simulated recording, through
`sclam` as a user runs it. Unusable input: exit status 2, one line
`sclam <command>: error: <reason>` on stderr, nothing written. A bad message inside a good
recording: exit status 0, the message dropped, counted under its reason and warned about."""
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
from pathlib import Path

import numpy as np
import pytest

from sclam_ros.cli.main import main
from sclam_ros.core.inputs import Scan
from sclam_ros.frontend import point_to_line
from sclam_ros.frontend.scan_matching import ScanMatcher
from sclam_ros.io import bag
from sclam_ros.sim import simulate

SCAN = "sensor_msgs/msg/LaserScan"
JOINT_STATE = "sensor_msgs/msg/JointState"
VENV_BIN = Path(sys.executable).parent


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


def rewrite(src, dst, change_scan):
    """Copy the encoder and scan topics of `src` into a new bag `dst` (with its params.yaml),
    each scan message replaced by change_scan(scan number, message)."""
    with bag.BagWriter(dst) as writer:
        number = 0
        for topic, t, msg in bag.iter_messages(src, ["/joint_states", "/scan"]):
            if topic == "/scan":
                msg = change_scan(number, msg)
                number += 1
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


def test_refinement_without_lines_keeps_the_icp_motion():
    """Outdoors, no walls: the reference scan has no points on lines, ReferenceScan is None.
    The match must come back as KISS-ICP found it, counted, instead of crashing."""
    rng = np.random.default_rng(3)
    trees = rng.uniform(-8, 8, (400, 2))  # scattered poles: no two neighbourhoods on a line
    matcher = point_to_line.RefinedScanMatcher(ScanMatcher())
    matches = 0
    for i in range(8):
        points = np.column_stack([trees - [0.03 * i, 0.0], np.zeros(len(trees))])  # laser frame
        scan = Scan(stamp=0.1 * i, ranges=np.hypot(points[:, 0], points[:, 1]), angle_min=-np.pi,
                    angle_increment=2 * np.pi / len(trees), range_min=0.0, range_max=30.0)
        match, z = matcher.add_scan(scan, np.array([0.03, 0.0, 0.0]), points)
        matches += match is not None
    assert point_to_line.ReferenceScan.from_points(points) is None
    assert matches > 1
    # Every match from the scan before it (all but the first after the map's warm-up) is one
    # the refinement had to leave alone.
    assert matcher.unrefined["no_lines"] == matches - 1
    assert np.allclose(z, [0.03, 0.0, 0.0], atol=0.01)


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
        assert counts[topic] == {"read": len(ids[topic]) - 1, "corrupt": 1}

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
    good = next(mcap_recording.glob("*.mcap")).read_bytes()
    broken = tmp_path / "broken"
    shutil.copytree(mcap_recording, broken)
    target = next(broken.glob("*.mcap"))
    for seed in range(60):
        rng = np.random.default_rng(seed)
        data = bytearray(good)
        at = int(len(data) * (region + 0.02 * rng.random()))
        data[at:at + 200] = rng.bytes(200)
        target.write_bytes(bytes(data))
        caplog.clear()
        counts = _read_counts(broken)
        if symptom(counts, info):
            break
    else:
        pytest.fail(f"no seed produced the symptom {case}")
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
    env = dict(os.environ, ROS_DOMAIN_ID=str(100 + os.getpid() % 100),
               RMW_IMPLEMENTATION=os.environ.get("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp"))
    process = subprocess.Popen([str(VENV_BIN / "sclam"), "play", str(recording)], cwd=tmp_path,
                               env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
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
