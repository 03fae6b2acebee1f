"""Bad recordings made from good ones, and what `sclam calibrate` must make of each (issue 13).

Every case is made from a short simulated recording (or one simulated with a degenerate
motion) by one change, declares what a user must get, and is run through `sclam calibrate`
and `sclam calibrate --track` as a user runs them: a subprocess, so that a traceback is seen
as the user would see it. Shared by bench/fuzz.py (the whole matrix) and test/test_fuzz.py
(a fast subset).

Outcomes of one run: "traceback" (or any exit status other than 0 and 2, or a timeout),
"nan" (a NaN or inf in what was written or printed), "error" (exit 2, one line `sclam
calibrate: error: <reason>`), "warning" (exit 0 and a warning: a good recording gives none), "unobservable" (exit 0, a parameter flagged not observed), "clean" (exit 0, none of
these). Exit 0 results are also compared with the truth: "wrong" lists the parameters more
than WRONG_SIGMA of their σ off it (and an unobserved one not at its nominal value).
"""
from __future__ import annotations

import dataclasses
import json
import math
import os
import re
import shutil
import sqlite3
import subprocess
import sys
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from sclam_ros.core.params import CALIBRATION_KEYS
from sclam_ros.io import bag
from sclam_ros.io.messages import stamp_to_sec
from sclam_ros.sim.record import simulate

SCAN = "sensor_msgs/msg/LaserScan"
JOINT_STATE = "sensor_msgs/msg/JointState"
TOPICS = ("/joint_states", "/scan")

# An exit-0 estimate this many σ from the truth is wrong. The σ of a 40 s recording are
# honest to about 1.5× (docs/accuracy.md); 5σ separates noise from a broken input.
WRONG_SIGMA = 5.0
RUN_TIMEOUT_S = 600
BOTH = ("batch", "track")


# --- the recordings the cases are made from ----------------------------------------------

SOURCE_DURATION = 40.0
SOURCES = {  # name -> simulate() arguments
    "good": dict(duration=SOURCE_DURATION),
    "good_mcap": dict(duration=SOURCE_DURATION, storage="mcap"),
    "straight": dict(duration=SOURCE_DURATION, motion="straight"),
    "spin": dict(duration=SOURCE_DURATION, motion="spin"),
    "still": dict(duration=SOURCE_DURATION, motion="still"),
    "short": dict(duration=3.0),
}


def make_source(name, folder, duration=None) -> Path:
    """Simulate the source recording `name` (SOURCES) into folder/name once; its path.
    `duration` shortens the long ones (the test's subset)."""
    out = Path(folder) / name
    if not (out / "truth.json").is_file():
        arguments = dict(SOURCES[name])
        if duration is not None and arguments["duration"] > duration:
            arguments["duration"] = duration
        simulate(out, robot="pioneer", seed=2, overwrite=True, **arguments)
    return out


def rewrite(src, dst, change_scan=None, change_joint_state=None, keep=TOPICS) -> Path:
    """Copy the input topics of `src` (those in `keep`) into a new bag `dst` with its
    params.yaml and truth.json, each message replaced by change_scan /
    change_joint_state(number on its topic, message)."""
    dst = Path(dst)
    with bag.BagWriter(dst) as writer:
        numbers = Counter()
        for topic, t, msg in bag.iter_messages(src, list(TOPICS)):
            change = change_scan if topic == "/scan" else change_joint_state
            if change is not None:
                msg = change(numbers[topic], msg)
            numbers[topic] += 1
            if topic in keep:
                writer.write(topic, SCAN if topic == "/scan" else JOINT_STATE, msg, t)
    for name in ("params.yaml", "truth.json"):
        shutil.copy(Path(src) / name, dst / name)
    return dst


def with_params(src, dst, edit) -> Path:
    """dst: the recording `src` unchanged (linked), params.yaml edited by edit(text)."""
    dst = Path(dst)
    dst.mkdir(parents=True)
    for path in Path(src).iterdir():
        if path.name != "params.yaml":
            os.symlink(path.resolve(), dst / path.name)
    (dst / "params.yaml").write_text(edit((Path(src) / "params.yaml").read_text()))
    return dst


# --- changes of messages -------------------------------------------------------------------


def at(numbers, change):
    """`change` of a message applied to the messages numbered `numbers` on their topic (a
    set; None: all of them; a callable: where it is true), as rewrite() calls it."""
    def changed(number, msg):
        hit = numbers is None or (numbers(number) if callable(numbers) else number in numbers)
        return change(msg) if hit else msg
    return changed


def fields(**values):
    return lambda msg: dataclasses.replace(msg, **values)


def extra_ranges(msg):
    return dataclasses.replace(msg, ranges=np.concatenate([msg.ranges, msg.ranges[:60]]))


def negative_increment_unreversed(msg):  # a mirrored scan: the angles contradict angle_max
    return dataclasses.replace(msg, angle_increment=-msg.angle_increment)


def negative_increment_reversed(msg):  # a scanner listing its beams clockwise: the same scan
    return dataclasses.replace(msg, ranges=msg.ranges[::-1].copy(), angle_min=msg.angle_max,
                               angle_max=msg.angle_min, angle_increment=-msg.angle_increment)


def all_ranges(value):
    return lambda msg: dataclasses.replace(msg, ranges=np.full_like(msg.ranges, value))


def holes(share):
    """A `share` of the beams without a return, as drivers report it: NaN, 0, inf or beyond
    range_max, a quarter each."""
    def change(msg):
        ranges = np.array(msg.ranges, np.float32)
        rng = np.random.default_rng(len(ranges) + int(msg.header.stamp.nanosec))
        missing = rng.random(len(ranges)) < share
        which = rng.integers(0, 4, len(ranges))
        for value, kind in ((np.nan, 0), (0.0, 1), (np.inf, 2), (msg.range_max + 5.0, 3)):
            ranges[missing & (which == kind)] = value
        return dataclasses.replace(msg, ranges=ranges)
    return change


def swap_joint_names(msg):
    return dataclasses.replace(msg, name=list(reversed(msg.name)))


def negate(*joints):
    def change(msg):
        position = np.array(msg.position, float)
        position[[msg.name.index(j) for j in joints]] *= -1.0
        return dataclasses.replace(msg, position=position)
    return change


def rename_joints(msg):
    return dataclasses.replace(msg, name=[f"wheel_{i}" for i in range(len(msg.name))])


def wrap_counter(modulus):
    """Positions (ticks) as a counter of `modulus` reports them: wrapped into [0, modulus)."""
    def change(msg):
        return dataclasses.replace(msg, position=np.mod(np.array(msg.position, float), modulus))
    return change


def non_finite_position(msg):
    position = np.array(msg.position, float)
    position[0] = np.nan
    return dataclasses.replace(msg, position=position)


def shift_header(offset):
    def change(msg):
        stamp = bag.time_msg(stamp_to_sec(msg.header.stamp) + offset)
        return dataclasses.replace(msg, header=dataclasses.replace(msg.header, stamp=stamp))
    return change


def relabel_frame(msg):
    return dataclasses.replace(msg, header=dataclasses.replace(msg.header, frame_id="laser_2"))


# --- cases ---------------------------------------------------------------------------------


@dataclass(frozen=True)
class Case:
    """One bad (or good) input and what a user must get from it.

    expect: "error" (exit 2, the reason line containing every needle), "warning" (exit 0, a
    warning containing every needle, the estimate right), "unobservable" (exit 0, at least
    the parameters in `unobserved` flagged and at nominal, the others right) or "clean" (exit
    0, no warning, the estimate right). `also`: other outcomes that are right too (a
    recording of 3 s may be refused or flagged)."""

    name: str
    make: Callable  # (sources folder, out folder) -> (bag path, params path)
    expect: str
    needles: tuple = ()
    also: tuple = ()
    unobserved: tuple = ()
    source: str = "good"
    fast: tuple = ()  # the runs ("batch", "track") in test/test_fuzz.py's fast subset


def _scan_case(name, numbers, change, needles, expect="warning", also=(), fast=()):
    def make(sources, out):
        bad = rewrite(sources / "good", out / "bag", change_scan=at(numbers, change))
        return bad, bad / "params.yaml"
    return Case(name, make, expect, tuple(needles), also=also, fast=fast)


def _joint_case(name, numbers, change, expect, needles, also=(), fast=()):
    def make(sources, out):
        bad = rewrite(sources / "good", out / "bag", change_joint_state=at(numbers, change))
        return bad, bad / "params.yaml"
    return Case(name, make, expect, tuple(needles), also=also, fast=fast)


def _params_case(name, edit, needles, fast=()):
    def make(sources, out):
        good = sources / "good"
        params = out / "params.yaml"
        out.mkdir(parents=True, exist_ok=True)
        content = edit(good, out)
        if isinstance(content, Path):
            return good, content
        if isinstance(content, bytes):
            params.write_bytes(content)
        else:
            params.write_text(content)
        return good, params
    return Case(name, make, "error", tuple(needles), fast=fast)


def _set(text, key, value):
    """params.yaml text with `key` set to `value` (the line replaced)."""
    return re.sub(rf"(\n\s+{key}: )[^\n]*", rf"\g<1>{value}", text)


def _case(name, source, expect, needles=(), also=(), unobserved=(), params_edit=None,
          fast=()):
    """A source recording as it is, or with its params.yaml changed by params_edit(text)."""
    def make(sources, out):
        src = sources / source
        if params_edit is None:
            return src, src / "params.yaml"
        changed = with_params(src, out / "bag", params_edit)
        return changed, changed / "params.yaml"
    return Case(name, make, expect, tuple(needles), also=also, unobserved=tuple(unobserved),
                source=source, fast=fast)


def _db3_message(which_topic, sql):
    """A copy of the good recording with one message of `which_topic` changed by `sql`
    (an UPDATE with one ? for the message's id): the 50th scan or the 300th joint state."""
    def make(sources, out):
        broken = out / "bag"
        shutil.copytree(sources / "good", broken)
        db = sqlite3.connect(next(broken.glob("*.db3")))
        ids = [row[0] for row in db.execute(
            "SELECT m.id FROM messages m JOIN topics t ON m.topic_id = t.id WHERE t.name = ? "
            "ORDER BY m.timestamp", (which_topic,))]
        db.execute(sql, (ids[50 if which_topic == "/scan" else 300],))
        db.commit()
        db.close()
        return broken, broken / "params.yaml"
    return make


def _truncated_db3(sources, out):
    broken = out / "bag"
    shutil.copytree(sources / "good", broken)
    db3 = next(broken.glob("*.db3"))
    data = db3.read_bytes()
    db3.write_bytes(data[: len(data) // 2])
    return broken, broken / "params.yaml"


def _dropped(counts, info):
    return any(counts.read[t] + counts.corrupt[t] < info[t][1] for t in TOPICS)


# Where random bytes land decides what breaks: mostly range values (undetectable: mcap's
# CRCs are not checked by rosbags), sometimes a record length (the reader raises, or drops
# the rest of a chunk). 200 bytes are sprayed at seeded places of the region until the named
# symptom shows (about one place in four), as in test_robustness.
MCAP_SYMPTOMS = {
    "storage_error": lambda counts, info: counts.unreadable > 0,
    "silent_drop": lambda counts, info: not counts.unreadable and _dropped(counts, info),
}


def spray_mcap(source, broken, region, symptom, topics=None):
    """Copy the rosbag2 folder `source` (one .mcap) to `broken` with 200 random bytes written at
    a seeded place of `region` (fraction of the file), trying seeds until ``symptom(counts,
    info)`` holds for what the reader then returns; that bag.ReadCounts, or RuntimeError."""
    info = bag.topic_info(source)
    good = next(Path(source).glob("*.mcap")).read_bytes()
    shutil.copytree(source, broken)
    target = next(Path(broken).glob("*.mcap"))
    for seed in range(60):
        rng = np.random.default_rng(seed)
        data = bytearray(good)
        at = int(len(data) * (region + 0.02 * rng.random()))
        data[at:at + 200] = rng.bytes(200)
        target.write_bytes(bytes(data))
        counts = bag.ReadCounts()
        for _ in bag.iter_messages(broken, list(topics or info), counts=counts):
            pass
        if symptom(counts, info):
            return counts
    raise RuntimeError("no seed produced the symptom")


def _mcap_bytes(region, symptom):
    def make(sources, out):
        import logging

        broken = out / "bag"
        quiet = logging.getLogger("sclam")
        level, quiet.level = quiet.level, logging.ERROR  # the probing reads warn: not the case's
        try:
            spray_mcap(sources / "good_mcap", broken, region, MCAP_SYMPTOMS[symptom], TOPICS)
        finally:
            quiet.level = level
        return broken, broken / "params.yaml"
    return make


def _empty_bag(sources, out):
    empty = out / "bag"
    with bag.BagWriter(empty):
        pass
    shutil.copy(sources / "good" / "params.yaml", empty / "params.yaml")
    return empty, empty / "params.yaml"


def _only(topic):
    def make(sources, out):
        kept = rewrite(sources / "good", out / "bag", keep=(topic,))
        return kept, kept / "params.yaml"
    return make


def _duplicated_joint_states(sources, out):
    """Every joint state recorded twice (two recorders, a relay): duplicates of a stamp."""
    src, dst = sources / "good", out / "bag"
    with bag.BagWriter(dst) as writer:
        for topic, t, msg in bag.iter_messages(src, list(TOPICS)):
            kind = SCAN if topic == "/scan" else JOINT_STATE
            writer.write(topic, kind, msg, t)
            if topic == "/joint_states":
                writer.write(topic, kind, msg, t + 1e-4)
    for name in ("params.yaml", "truth.json"):
        shutil.copy(src / name, dst / name)
    return dst, dst / "params.yaml"


def _wrapped(modulus, configured):
    def make(sources, out):
        bad = rewrite(sources / "good", out / "bag",
                      change_joint_state=at(None, wrap_counter(modulus)))
        if configured:
            params = bad / "params.yaml"
            params.write_text(_set(params.read_text(), "encoder_wrap", f"{modulus:.1f}"))
        return bad, bad / "params.yaml"
    return make


def _yaw_flipped(text):
    return _set(text, "laser_yaw", f"{math.pi:.6f}")


def _binary_params(good, out):
    return next(good.glob("*.db3")).read_bytes()[:4096]


def _folder_params(good, out):
    (out / "folder").mkdir()
    return out / "folder"


def _missing_params(good, out):
    return out / "no_such.yaml"


def cases() -> list:
    inc = "scan_ranges_angles_mismatch"
    return [
        # Good recordings: must stay clean and right.
        _case("good_db3", "good", "clean", fast=BOTH),
        _case("good_mcap", "good_mcap", "clean"),
        # Scan geometry (one scan of 400 broken): that scan dropped, counted, warned about.
        _scan_case("nan_angle_min_first_scan", {0}, fields(angle_min=math.nan),
                   ["scan_non_finite_angles"], fast=("batch",)),
        _scan_case("nan_angle_increment", {30}, fields(angle_increment=math.nan),
                   ["scan_non_finite_angles"]),
        _scan_case("inf_angle_increment", {30}, fields(angle_increment=math.inf),
                   ["scan_non_finite_angles"]),
        _scan_case("zero_angle_increment", {30}, fields(angle_increment=0.0),
                   ["scan_zero_angle_increment"], fast=("track",)),
        _scan_case("huge_angle_increment", {30}, fields(angle_increment=1e3), [inc]),
        _scan_case("huge_angle_increment_consistent", {30},
                   fields(angle_increment=1e3, angle_max=-math.pi + 359e3),
                   ["scan_angles_span_over_a_turn"]),
        _scan_case("negative_increment_unreversed", {60}, negative_increment_unreversed, [inc]),
        _scan_case("extra_ranges", {50}, extra_ranges, [inc]),
        # ... and every scan broken: nothing to match.
        _scan_case("zero_increment_every_scan", None, fields(angle_increment=0.0),
                   ["scan_zero_angle_increment"], expect="error"),
        _scan_case("negative_increment_unreversed_every_scan", None,
                   negative_increment_unreversed, [inc], expect="error"),
        _scan_case("all_inf_scans", None, all_ranges(np.inf), [], expect="error"),
        _scan_case("all_zero_scans", None, all_ranges(0.0), [], expect="error"),
        # Valid scans a real driver sends: the same calibration.
        _scan_case("negative_increment_reversed", None, negative_increment_reversed, [],
                   expect="clean"),
        _scan_case("third_of_beams_without_return", None, holes(1 / 3), [], expect="clean"),
        # Sparse enough that registrations fail: warning about them is right too.
        _scan_case("two_thirds_of_beams_without_return", None, holes(2 / 3), [],
                   expect="clean", also=("warning",)),
        # Topics.
        _case("scan_topic_wrong_type", "good", "error",
              ["scan_topic", "/ground_truth/odom", "nav_msgs/msg/Odometry"],
              params_edit=lambda t: _set(t, "scan_topic", "/ground_truth/odom"), fast=("track",)),
        _case("joint_states_topic_wrong_type", "good", "error",
              ["joint_states_topic", "nav_msgs/msg/Odometry"],
              params_edit=lambda t: _set(t, "joint_states_topic", "/ground_truth/odom")),
        _case("scan_topic_missing", "good", "error", ["/laser_scan"],
              params_edit=lambda t: _set(t, "scan_topic", "/laser_scan")),
        Case("no_scans_in_bag", _only("/joint_states"), "error", ("/scan",)),
        Case("no_joint_states_in_bag", _only("/scan"), "error", ("/joint_states",)),
        # Parameters files.
        _params_case("params_folder", _folder_params, ["is a folder"], fast=("batch",)),
        _params_case("params_missing", _missing_params, ["no_such.yaml"]),
        _params_case("params_binary", _binary_params, ["not a text file"]),
        _params_case("params_not_yaml", lambda g, o: "sclam:\n  ros__parameters: [unclosed\n",
                     ["not valid YAML"]),
        _params_case("params_empty", lambda g, o: "", ["empty"]),
        _params_case("params_unknown_key",
                     lambda g, o: (g / "params.yaml").read_text().replace("wheel_base:",
                                                                          "wheel_bas:"),
                     ["unknown parameter", "wheel_bas"]),
        _params_case("params_huge_radius",
                     lambda g, o: _set((g / "params.yaml").read_text(), "wheel_radius_left",
                                       "1.0e+300"), ["wheel_radius_left"]),
        _params_case("params_negative_base",
                     lambda g, o: _set((g / "params.yaml").read_text(), "wheel_base", "-0.3"),
                     ["wheel_base"]),
        _params_case("params_nan_laser_x",
                     lambda g, o: _set((g / "params.yaml").read_text(), "laser_x", ".nan"),
                     ["laser_x"]),
        _params_case("params_radius_is_text",
                     lambda g, o: _set((g / "params.yaml").read_text(), "wheel_radius_right",
                                       "big"), ["wheel_radius_right"]),
        _case("params_laser_yaw_180_off", "good", "error", ["laser_yaw 180° off"],
              params_edit=_yaw_flipped),
        # Storage.
        Case("db3_corrupt_message", _db3_message(
            "/joint_states", "UPDATE messages SET data = randomblob(length(data)) WHERE id = ?"),
            "warning", ("corrupt /joint_states message",), fast=("batch",)),
        Case("db3_truncated_message", _db3_message(
            "/scan", "UPDATE messages SET data = substr(data, 1, 20) WHERE id = ?"),
            "warning", ("corrupt /scan message",)),
        Case("db3_file_cut_in_half", _truncated_db3, "error", also=("warning",)),
        Case("mcap_random_bytes_near_end", _mcap_bytes(0.96, "storage_error"), "warning",
             ("the metadata announces",), source="good_mcap"),
        Case("mcap_random_bytes_middle", _mcap_bytes(0.5, "silent_drop"), "warning",
             ("the metadata announces",), source="good_mcap"),
        Case("empty_bag", _empty_bag, "error"),
        Case("bag_missing", lambda s, o: (o / "no_such_bag", s / "good" / "params.yaml"),
             "error", ("no_such_bag",)),
        # Wiring: refused, naming the fix.
        _joint_case("swapped_wheels", None, swap_joint_names, "error",
                    ["contradict the laser", "swapped"], fast=BOTH),
        _joint_case("left_encoder_backwards", None, negate("left_wheel_joint"), "error",
                    ["contradict the laser", "left wheel's encoder"]),
        _joint_case("right_encoder_backwards", None, negate("right_wheel_joint"), "error",
                    ["contradict the laser", "right wheel's encoder"]),
        _joint_case("both_encoders_backwards", None, negate("left_wheel_joint", "right_wheel_joint"),
                    "error", ["contradict the laser", "counts backwards"], fast=("track",)),
        _joint_case("wrong_joint_names", None, rename_joints, "error", ["joint"]),
        # Encoders.
        Case("encoder_wrap_configured", _wrapped(4096, True), "clean"),
        Case("encoder_wrap_unconfigured", _wrapped(4096, False), "warning", ("encoder",)),
        _joint_case("joint_state_nan_position", lambda n: n % 50 == 49, non_finite_position,
                    "warning", ["joint_state_non_finite"]),
        Case("joint_states_recorded_twice", _duplicated_joint_states, "clean",
             also=("warning",)),
        # Clocks and frames: repaired or flagged, and warned about.
        _joint_case("joint_state_headers_3s_off", None, shift_header(3.0), "warning",
                    ["/joint_states header stamps are +3.000 s off"], fast=("track",)),
        _scan_case("scan_headers_5s_off", None, shift_header(5.0),
                   ["/scan header stamps are +5.000 s off"]),
        # From the 150th scan on another frame_id (a second laser, a renamed one).
        _scan_case("scan_frame_id_changes", lambda n: n >= 150, relabel_frame,
                   ["frame_id changes"]),
        # Degenerate motion: what the data does not determine stays nominal, flagged.
        _case("standing_still", "still", "unobservable", also=("error",),
              unobserved=CALIBRATION_KEYS),
        _case("straight_only", "straight", "unobservable",
              unobserved=("wheel_base", "laser_x", "laser_y"), fast=("track",)),
        _case("spin_only", "spin", "unobservable"),
        _case("too_short", "short", "unobservable", also=("error",)),
    ]


CASES = {case.name: case for case in cases()}


# --- running and judging -------------------------------------------------------------------


@dataclass
class Outcome:
    kind: str  # traceback | nan | error | warning | unobservable | clean
    detail: str = ""  # the error line, or the warnings
    warnings: list = field(default_factory=list)
    unobserved: list = field(default_factory=list)
    wrong: dict = field(default_factory=dict)  # parameter -> error in σ (exit 0 only)
    exit_code: int = 0

    def short(self) -> str:
        text = self.kind
        if self.kind == "unobservable":
            text += "(" + ",".join(_SHORT[k] for k in self.unobserved) + ")"
        if self.wrong:
            text += " WRONG(" + ",".join(f"{_SHORT[k]} {v:+.0f}σ" for k, v in self.wrong.items()) + ")"
        return text


_SHORT = dict(zip(CALIBRATION_KEYS, ("rL", "rR", "b", "lx", "ly", "lθ")))


def _estimate_from_json(path):
    out = json.loads(Path(path).read_text())
    return ({k: out[k] for k in CALIBRATION_KEYS}, out["sigma"], out["observable"],
            out.get("nominal", {}))


def _estimate_from_track(path):
    lines = Path(path).read_text().splitlines()
    header, rows = lines[0].split(","), [line.split(",") for line in lines[1:]]
    last = dict(zip(header, map(float, rows[-1])))
    return ({k: last[k] for k in CALIBRATION_KEYS},
            {k: last[f"sigma_{k}"] for k in CALIBRATION_KEYS},
            {k: bool(last[f"observable_{k}"]) for k in CALIBRATION_KEYS}, {})


def _numbers(value):
    if isinstance(value, dict):
        for item in value.values():
            yield from _numbers(item)
    elif isinstance(value, list):
        for item in value:
            yield from _numbers(item)
    elif isinstance(value, (int, float)) and not isinstance(value, bool):
        yield float(value)


def _non_finite_written(path, track) -> bool:
    """A NaN or inf among the numbers of the output (not in the text of a warning in it)."""
    text = Path(path).read_text()
    if track:
        values = [float(v) for line in text.splitlines()[1:] for v in line.split(",")]
    else:
        values = list(_numbers(json.loads(text)))
    return not all(math.isfinite(v) for v in values)


def _non_finite_printed(stdout) -> bool:
    """A nan or inf in the printed table (words only: 'info' is no inf)."""
    return re.search(r"(?<![A-Za-z_])[-+]?(nan|inf)(?![A-Za-z_])", stdout, re.IGNORECASE) is not None


def run_case(bag_path, params_path, out_dir, track=False, truth=None) -> Outcome:
    """Run `sclam calibrate` (or with --track) as a subprocess and judge what it gave."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    result = out_dir / ("track.csv" if track else "calibration.json")
    command = [sys.executable, "-m", "sclam_ros.cli.main", "calibrate", str(bag_path),
               "--params", str(params_path), "--quiet",
               *(["--track", str(result)] if track else ["--json", str(result)])]
    env = dict(os.environ, MPLBACKEND="Agg", OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1")
    try:
        proc = subprocess.run(command, capture_output=True, text=True, timeout=RUN_TIMEOUT_S,
                              env=env)
    except subprocess.TimeoutExpired:
        return Outcome("traceback", f"timeout after {RUN_TIMEOUT_S} s", exit_code=-1)
    err = proc.stderr
    (out_dir / "stdout.txt").write_text(proc.stdout)  # to read after a bench run
    (out_dir / "stderr.txt").write_text(err)
    lines = [line for line in err.splitlines() if line.strip()]
    # A good recording gives no warning (the map warm-up is an info): each names a problem.
    named = [line.split(": warning: ", 1)[1] for line in lines if ": warning: " in line]
    if "Traceback" in err or proc.returncode not in (0, 2):
        tail = [line for line in lines if line.strip()][-1:] or [f"exit {proc.returncode}"]
        return Outcome("traceback", tail[0], named, exit_code=proc.returncode)
    if proc.returncode == 2:
        errors = [line for line in lines if line.startswith("sclam calibrate: error: ")]
        kind = "error" if len(errors) == 1 and not result.exists() else "traceback"
        detail = errors[0] if len(errors) == 1 else " | ".join(lines[-3:])
        if result.exists():
            detail += " (and wrote its output)"
        return Outcome(kind, detail, named, exit_code=2)
    if (not result.exists() or _non_finite_written(result, track)
            or _non_finite_printed(proc.stdout)):
        return Outcome("nan", "no output" if not result.exists() else "non-finite value written",
                       named)
    estimate, sigma, observable, nominal = (_estimate_from_track if track else
                                            _estimate_from_json)(result)
    unobserved = [k for k in CALIBRATION_KEYS if not observable[k]]
    wrong = {}
    if truth is not None:
        nominal = nominal or truth.get("nominal", {})
        for key in CALIBRATION_KEYS:
            if observable[key]:
                off = (estimate[key] - truth[key]) / sigma[key]
                if abs(off) > WRONG_SIGMA:
                    wrong[key] = off
            elif key in nominal and not math.isclose(estimate[key], nominal[key], rel_tol=1e-9,
                                                     abs_tol=1e-12):
                wrong[key] = (estimate[key] - nominal[key]) / sigma[key]
    kind = "warning" if named else "unobservable" if unobserved else "clean"
    return Outcome(kind, " | ".join(named), named, unobserved, wrong)


def judge(case: Case, outcome: Outcome) -> bool:
    """True if the outcome is what the case declares."""
    if outcome.kind in ("traceback", "nan") or outcome.wrong:
        return False
    accepted = {case.expect, *case.also}
    if outcome.kind == "error":
        return "error" in accepted and all(n in outcome.detail for n in case.needles)
    if accepted == {"error"}:
        return False  # exit 0 where no answer can be right
    if case.expect == "unobservable":
        return bool(outcome.unobserved) and set(outcome.unobserved) >= set(case.unobserved)
    if outcome.unobserved:
        return False  # a drive that excites every parameter left one unobserved
    if case.expect in ("warning", "error"):  # exit 0 is right only with the problem named
        return any(all(n in w for n in case.needles) for w in outcome.warnings)
    return outcome.kind == "clean" or "warning" in accepted


def silently_wrong(case: Case, outcome: Outcome) -> bool:
    """Exit 0 with a result that is wrong, or with a problem that went unnamed."""
    return outcome.kind in ("warning", "unobservable", "clean") and not judge(case, outcome)


def run(case: Case, sources, work, track=False) -> Outcome:
    """Make the case in work/<name> from the sources folder and run it."""
    work = Path(work) / case.name
    made = work / ("made_track" if track else "made")
    if made.exists():
        shutil.rmtree(made)
    bag_path, params_path = case.make(Path(sources), made)
    truth_path = Path(sources) / case.source / "truth.json"
    truth = json.loads(truth_path.read_text()) if truth_path.is_file() else None
    return run_case(bag_path, params_path, work / ("track" if track else "batch"), track, truth)
