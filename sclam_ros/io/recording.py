"""Run a recording through the same frontend the live node uses, as fast as possible."""
from __future__ import annotations

import logging
from collections import Counter
from dataclasses import dataclass, field

import numpy as np

from sclam_ros.io import bag
from sclam_ros.io.messages import (
    MessageRejected,
    check_scan,
    joint_state_wheels,
    laser_scan_to_scan,
    odometry_to_pose,
    quaternion_yaw,
    side_position,
    stamp_to_sec,
)
from sclam_ros.frontend.odometry_wheels import WheelsFromOdometry
from sclam_ros.frontend.wheel_sides import SideDisagreement
from sclam_ros.frontend.pipeline import Frontend
from sclam_ros.core.inputs import Rejections

log = logging.getLogger("sclam")

GROUND_TRUTH_TOPIC = "/ground_truth/odom"


@dataclass
class Recording:
    """What a bag yields for the estimator: keyframes, rejections and counts."""

    keyframes: list
    rejections: Rejections
    messages: dict = field(default_factory=dict)  # topic -> {read, used, corrupt} (bag.ReadCounts)
    frontend: Frontend = None
    # a skid-steer's wheels of each side compared (SideDisagreement.summary); None otherwise
    wheel_sides: dict = None
    # what the front end did (FrontendReport): of `frontend`, or joined from a recording's
    # chunks (fleet/chunked.py), which keep no front end
    report: object = None

    def __post_init__(self):
        if self.report is None and self.frontend is not None:
            self.report = self.frontend.report()


# What each input topic must carry; anything else is a misconfigured topic name.
JOINT_STATE_TYPE = "sensor_msgs/msg/JointState"
LASER_SCAN_TYPE = "sensor_msgs/msg/LaserScan"
ODOMETRY_TYPE = "nav_msgs/msg/Odometry"


def wheel_input(params) -> tuple:
    """(parameter name, topic, message type) of the wheel input: the Odometry topic when
    odometry_topic is set, else the JointState topic."""
    if params.odometry_topic:
        return "odometry_topic", params.odometry_topic, ODOMETRY_TYPE
    return "joint_states_topic", params.joint_states_topic, JOINT_STATE_TYPE


def check_topic_types(info: dict, params) -> None:
    """BagError if a configured input topic of the bag (``info``: bag.topic_info) carries
    another message type: its messages would lack every field the conversions read."""
    wheel_key, _, wheel_type = wheel_input(params)
    for key, wanted in ((wheel_key, wheel_type), ("scan_topic", LASER_SCAN_TYPE)):
        topic = getattr(params, key)
        msgtype = info.get(topic, (wanted,))[0]
        if msgtype != wanted:
            raise bag.BagError(f"{key} {topic} carries {msgtype}, not {wanted}")


# Header stamps whose offsets from their record stamps differ between the two input topics
# by more than this come from two clocks (a sensor computer that is not synchronised, a
# driver stamping with its own time), not from transport latency (ms) or a scan's duration
# (≤ 0.1 s). Paired across two clocks, each odometry edge covers another stretch of time
# than its scan match: wheel base +22 % at 3 s.
CLOCK_MISMATCH_S = 0.5
CLOCK_SAMPLE = 20  # messages per topic the offsets are judged from
CLOCK_HOLD_MAX = 5000  # messages held back at most while waiting for both topics


class HeaderClocks:
    """Puts both input topics' header stamps on one clock. Each topic's offset (header −
    record stamp, median of its first messages) is measured; a topic whose offset differs
    from the other's by more than CLOCK_MISMATCH_S is moved by the difference onto the clock
    of the other, the one nearer to record time. Header stamps keep their precision within
    a topic (record stamps carry the recorder's scheduling jitter)."""

    def __init__(self, topics):
        self.samples = {topic: [] for topic in topics}
        self.shift = None  # {topic: s subtracted from its header stamps}, once decided

    def add(self, topic, header_s, record_s) -> bool:
        """Sample one message; True once every topic has enough samples."""
        if len(self.samples[topic]) < CLOCK_SAMPLE:
            self.samples[topic].append(header_s - record_s)
        return all(len(s) >= CLOCK_SAMPLE for s in self.samples.values())

    def decide(self) -> None:
        self.shift = dict.fromkeys(self.samples, 0.0)
        offsets = {t: float(np.median(s)) for t, s in self.samples.items() if s}
        if len(offsets) < 2:
            return
        (near, o_near), (far, o_far) = sorted(offsets.items(), key=lambda item: abs(item[1]))
        if abs(o_far - o_near) > CLOCK_MISMATCH_S:
            self.shift[far] = o_far - o_near
            log.warning("%s header stamps are %+.3f s off their record stamps (%s: %+.3f s): "
                        "its stamps are moved by %+.3f s onto the clock of %s", far, o_far,
                        near, o_near, o_near - o_far, near)


_REJECTED = object()
# JointState messages looked at for the wheel joints before the recording is read: a driver
# may publish a robot's joints in several messages, but not spread over more than this.
JOINT_CHECK_MESSAGES = 50


def check_wheel_joints(path, params) -> None:
    """BagError if a skid-steer's wheel joints are not in the first JointState messages, or
    not together in one: each message is averaged per side as a whole."""
    _, topic, _ = wheel_input(params)
    joints = [j for side in params.wheel_joints() for j in side]
    seen, whole = set(), False
    messages = bag.iter_messages(path, [topic])
    try:
        for _, (_, _, msg) in zip(range(JOINT_CHECK_MESSAGES), messages):
            names = set(msg.name)
            seen |= names
            whole = whole or names.issuperset(joints)
    finally:
        messages.close()
    if not seen:
        return  # no message: the count of what was read says so
    absent = [j for j in joints if j not in seen]
    if absent:
        raise bag.BagError(
            f"wheel joint(s) {', '.join(absent)} not in {topic} (its joints: "
            f"{', '.join(sorted(seen))}): set left_wheel_joints and right_wheel_joints to the "
            "names of each side's wheels")
    if not whole:
        raise bag.BagError(
            f"{topic} carries the wheel joints {', '.join(joints)} in separate messages: a "
            "side's wheels are averaged within one message; publish them in one JointState "
            "(as joint_state_broadcaster does)")



def check_odometry_frame(path, params) -> None:
    """BagError if the first message on odometry_topic is the motion of another frame than
    base_frame: the laser pose would be calibrated on one frame, the wheels on another."""
    messages = bag.iter_messages(path, [params.odometry_topic])
    try:
        first = next(messages, None)
    finally:
        messages.close()
    child = str(first[2].child_frame_id).lstrip("/") if first is not None else ""
    if child and child != params.base_frame.lstrip("/"):
        raise bag.BagError(
            f"odometry_topic {params.odometry_topic} is the motion of {child}, not of base_frame "
            f"{params.base_frame}: set base_frame: {child} (the laser pose is then taken on "
            f"{child}), or name the Odometry topic of {params.base_frame}")


def _explain_odometry_input(params) -> None:
    log.info("wheel input: %s (nav_msgs/Odometry), turned back into wheel rotations with the "
             "nominal wheel_radius_left %.4f m, wheel_radius_right %.4f m, wheel_base %.4f m. "
             "This assumes it is the wheels' own odometry, computed with these values; where "
             "the base fuses an IMU or other sensors into it, its heading is not the wheels' "
             "and the wheel base estimated is that of the fused heading",
             params.odometry_topic, params.wheel_radius_left, params.wheel_radius_right,
             params.wheel_base)


def _warn_about_odometry(odometry: WheelsFromOdometry, topic) -> None:
    """Say what in the odometry itself shows that its heading is not only the wheels'."""
    if odometry.sideways:
        log.warning("%d of %d increments of %s move sideways (%.0f mm in all over %.1f m "
                    "driven), which no wheel rotation makes; the sideways part is dropped. A "
                    "differential drive's wheel odometry never does: this odometry fuses other "
                    "sensors, and its heading is not the wheels'", odometry.sideways,
                    odometry.increments, topic, 1e3 * odometry.sideways_total, odometry.path)
    if odometry.twist_disagrees():
        log.warning("%s: the turn rate in its twist adds up to %.1f rad, its poses turn by %.1f "
                    "rad: the heading comes from another source than the velocities (a fused "
                    "IMU?), and the wheel base estimated is that of the heading", topic,
                    odometry.turning_twist, odometry.turning_poses)


def iter_outputs(path, params, sink, progress=None, start=None, stop=None, counts=None,
                 odometry=None, sides=None, watch=None):
    """Feed a bag's messages in record order to `sink` (a Frontend or an OnlineCalibrator:
    anything with add_encoder, add_scan and rejections), through the same conversions the
    node uses; yield what each call returns. `start`/`stop`: record-time window (s).
    `counts`: a bag.ReadCounts to fill (messages read, used and corrupt per topic).
    `odometry`: the WheelsFromOdometry that turns an odometry_topic into wheel angles (one
    with the default configuration if not given). `sides`: the SideDisagreement a
    skid-steer's wheels are compared in (one with the default configuration if not given).
    `watch`: a SpanWatch told the record time of each message before it is fed.

    A message the conversions refuse is counted in the sink's rejections under its reason
    and warned about the first time that reason occurs; the others are used. Header stamps
    are put on one clock (HeaderClocks): the first messages are held back until it is known."""
    _, wheel_topic, _ = wheel_input(params)
    topics = [wheel_topic, params.scan_topic]
    info = bag.topic_info(path)
    check_topic_types(info, params)
    if params.odometry_topic:
        check_odometry_frame(path, params)
        odometry = odometry or WheelsFromOdometry(params)
        _explain_odometry_input(params)
    elif params.wheels_per_side > 1:
        check_wheel_joints(path, params)
    sides = sides or SideDisagreement(params)
    total = sum(info.get(t, (None, 0))[1] for t in topics)
    if start is not None or stop is not None:  # a window: estimate its share of the messages
        first, last = bag.time_span(path)
        lo, hi = max(first, start or first), min(last, stop or last)
        total = int(total * max(0.0, hi - lo) / max(last - first, 1e-9))
    counts = counts if counts is not None else bag.ReadCounts()
    clocks = HeaderClocks(topics)
    frames = Counter()  # scans per header.frame_id

    def feed(topic, record_time, msg):
        if watch is not None:
            watch.at(record_time)
        shift = clocks.shift[topic]
        try:
            if topic == wheel_topic and params.odometry_topic:
                stamp, pose, yaw_rate = odometry_to_pose(msg, params)
                left, right = odometry.add(stamp, pose, yaw_rate)
                output = sink.add_encoder(stamp - shift, left, right)
            elif topic == wheel_topic:
                stamp, left, right = joint_state_wheels(msg, params)
                sides.add(left, right)
                output = sink.add_encoder(stamp - shift, side_position(left, params.encoder_wrap),
                                          side_position(right, params.encoder_wrap))
            else:
                scan = laser_scan_to_scan(msg)
                scan.stamp -= shift
                frames[scan.frame_id] += 1
                check_scan(scan)  # the node's gate (ros/node.py _on_scan)
                output = sink.add_scan(scan)
        except MessageRejected as exc:
            if exc.reason not in sink.rejections.counts:
                log.warning("rejecting %s messages (counted): %s", topic, exc)
            sink.rejections.add(exc.reason)
            return _REJECTED
        counts.used[topic] += counts.covers(record_time)
        return output

    def fed(messages):
        outputs = (feed(*message) for message in messages)
        return (output for output in outputs if output is not _REJECTED)

    held = []  # messages read before the clocks are decided
    for seen, (topic, t, msg) in enumerate(bag.iter_messages(path, topics, start, stop, counts), 1):
        if progress is not None and seen % 500 == 0:
            progress(seen, total)
        if clocks.shift is not None:
            yield from fed([(topic, t, msg)])
            continue
        held.append((topic, t, msg))
        if clocks.add(topic, stamp_to_sec(msg.header.stamp), t) or len(held) >= CLOCK_HOLD_MAX:
            clocks.decide()
            yield from fed(held)
            held = []
    if clocks.shift is None:  # fewer messages than the sample
        clocks.decide()
        yield from fed(held)
    if len(frames) > 1:
        log.warning("%s: header.frame_id changes within the recording (%s); the calibration "
                    "takes every scan as coming from one laser", params.scan_topic,
                    ", ".join(f"{frame}: {n} scans" for frame, n in frames.most_common()))
    if params.odometry_topic:
        _warn_about_odometry(odometry, wheel_topic)
    for line in sides.warnings():
        log.warning("%s", line)
    if progress is not None:
        progress(total, total)


class SpanWatch:
    """What a front end counted while it was fed the messages of a record-time span
    [lo, hi) (s; None: open): its rejections and its report's counts from the first
    message at or after lo to the first at or after hi (or the end). A recording cut into
    chunks (fleet/chunked.py) reads a lead and a tail around each span; counted by span,
    the chunks' counts add up to what one sequential pass counts, but for what a chunk's
    new local map changes."""

    def __init__(self, frontend, span=(None, None)):
        self.frontend = frontend
        self.lo, self.hi = span
        self.entered = self._snapshot() if self.lo is None else None
        self.left = None

    def _snapshot(self):
        return Counter(self.frontend.rejections.counts), self.frontend.report()

    def at(self, record_time: float) -> None:
        if self.entered is None and record_time >= self.lo:
            self.entered = self._snapshot()
        if self.left is None and self.hi is not None and record_time >= self.hi:
            self.entered = self.entered or self._snapshot()
            self.left = self._snapshot()

    def counted(self):
        """(Rejections, FrontendReport) of the span."""
        end = self.left or self._snapshot()
        start = self.entered or end
        return Rejections(end[0] - start[0]), end[1].since(start[1])


def iter_keyframes(path, params, frontend=None, progress=None, start=None, stop=None, counts=None,
                   sides=None, watch=None):
    """Yield keyframes from a bag (or its record-time window [start, stop)) in record order."""
    frontend = frontend or Frontend(params)
    for keyframes in iter_outputs(path, params, frontend, progress, start, stop, counts,
                                  sides=sides, watch=watch):
        yield from keyframes
    yield from frontend.flush()


def read_recording(path, params, progress=None, start=None, stop=None,
                   keep_scan_points=False, counted=(None, None), scan_period=None) -> Recording:
    """keep_scan_points: the keyframes carry their scans' points (for `sclam diagnose`'s
    map of walls). counted: the record-time span (s) whose messages, rejections and front
    end counts the Recording counts (bag.ReadCounts.span, SpanWatch); the whole recording
    unless given. scan_period: the laser's period measured on the recording's first scans,
    for a read that starts later (frontend/decimation.py)."""
    frontend = Frontend(params, keep_scan_points=keep_scan_points, scan_period=scan_period)
    counts = bag.ReadCounts(span=counted)
    sides = SideDisagreement(params)
    if counted == (None, None):
        keyframes = list(iter_keyframes(path, params, frontend, progress, start, stop, counts,
                                        sides))
        return Recording(keyframes, frontend.rejections, counts.as_dict(), frontend,
                         sides.summary())
    watch = SpanWatch(frontend, counted)
    keyframes = list(iter_keyframes(path, params, frontend, progress, start, stop, counts, sides,
                                    watch))
    rejections, report = watch.counted()
    return Recording(keyframes, rejections, counts.as_dict(), frontend, sides.summary(), report)


def scan_frame_id(path, topic):
    """header.frame_id of the first message on `topic` (the laser frame), or None."""
    messages = bag.iter_messages(path, [topic])
    try:
        first = next(messages, None)
    finally:
        messages.close()  # the bag's reader with it, now rather than at garbage collection
    return (str(first[2].header.frame_id) or None) if first is not None else None


def read_ground_truth(path, topic=GROUND_TRUTH_TOPIC):
    """(stamps, poses) of a ground-truth nav_msgs/Odometry topic, or None if the bag has none."""
    if topic not in bag.topic_info(path):
        return None
    stamps, poses = [], []
    for _, _, msg in bag.iter_messages(path, [topic]):
        yaw = quaternion_yaw(msg.pose.pose.orientation)
        stamps.append(stamp_to_sec(msg.header.stamp))
        poses.append((msg.pose.pose.position.x, msg.pose.pose.position.y, yaw))
    return np.array(stamps), np.array(poses)
