"""Run a recording through the same frontend the live node uses, as fast as possible."""
from __future__ import annotations

import logging
from dataclasses import dataclass, field

from sclam_ros.io import bag
from sclam_ros.io.messages import MessageRejected, joint_state_to_raw, laser_scan_to_scan
from sclam_ros.frontend.pipeline import Frontend
from sclam_ros.core.inputs import Rejections

log = logging.getLogger("sclam")

GROUND_TRUTH_TOPIC = "/ground_truth/odom"


@dataclass
class Recording:
    """What a bag yields for the estimator: keyframes, rejections and counts."""

    keyframes: list
    rejections: Rejections
    messages: dict = field(default_factory=dict)  # topic -> {read, corrupt} (bag.ReadCounts)
    frontend: Frontend = None


# What each input topic must carry; anything else is a misconfigured topic name.
JOINT_STATE_TYPE = "sensor_msgs/msg/JointState"
LASER_SCAN_TYPE = "sensor_msgs/msg/LaserScan"


def check_topic_types(info: dict, params) -> None:
    """BagError if a configured input topic of the bag (``info``: bag.topic_info) carries
    another message type: its messages would lack every field the conversions read."""
    for key, wanted in (("joint_states_topic", JOINT_STATE_TYPE), ("scan_topic", LASER_SCAN_TYPE)):
        topic = getattr(params, key)
        msgtype = info.get(topic, (wanted,))[0]
        if msgtype != wanted:
            raise bag.BagError(f"{key} {topic} carries {msgtype}, not {wanted}")


def iter_outputs(path, params, sink, progress=None, start=None, stop=None, counts=None):
    """Feed a bag's messages in record order to `sink` (a Frontend or an OnlineCalibrator:
    anything with add_encoder, add_scan and rejections), through the same conversions the
    node uses; yield what each call returns. `start`/`stop`: record-time window (s).
    `counts`: a bag.ReadCounts to fill (messages read and corrupt per topic).

    A message the conversions refuse is counted in the sink's rejections under its reason
    and warned about the first time that reason occurs; the others are used."""
    topics = [params.joint_states_topic, params.scan_topic]
    info = bag.topic_info(path)
    check_topic_types(info, params)
    total = sum(info.get(t, (None, 0))[1] for t in topics)
    if start is not None or stop is not None:  # a window: estimate its share of the messages
        first, last = bag.time_span(path)
        lo, hi = max(first, start or first), min(last, stop or last)
        total = int(total * max(0.0, hi - lo) / max(last - first, 1e-9))
    messages = bag.iter_messages(path, topics, start, stop, counts)
    for seen, (topic, _, msg) in enumerate(messages, 1):
        if progress is not None and seen % 500 == 0:
            progress(seen, total)
        try:
            if topic == params.joint_states_topic:
                output = sink.add_encoder(*joint_state_to_raw(msg, params))
            else:
                output = sink.add_scan(laser_scan_to_scan(msg))
        except MessageRejected as exc:
            if exc.reason not in sink.rejections.counts:
                log.warning("rejecting %s messages (counted): %s", topic, exc)
            sink.rejections.add(exc.reason)
            continue
        yield output
    if progress is not None:
        progress(total, total)


def iter_keyframes(path, params, frontend=None, progress=None, start=None, stop=None, counts=None):
    """Yield keyframes from a bag (or its record-time window [start, stop)) in record order."""
    frontend = frontend or Frontend(params)
    for keyframes in iter_outputs(path, params, frontend, progress, start, stop, counts):
        yield from keyframes
    yield from frontend.flush()


def read_recording(path, params, progress=None, start=None, stop=None) -> Recording:
    frontend = Frontend(params)
    counts = bag.ReadCounts()
    keyframes = list(iter_keyframes(path, params, frontend, progress, start, stop, counts))
    return Recording(keyframes, frontend.rejections, counts.as_dict(), frontend)


def read_ground_truth(path, topic=GROUND_TRUTH_TOPIC):
    """(stamps, poses) of a ground-truth nav_msgs/Odometry topic, or None if the bag has none."""
    import numpy as np

    from sclam_ros.io.messages import stamp_to_sec

    if topic not in bag.topic_info(path):
        return None
    stamps, poses = [], []
    for _, _, msg in bag.iter_messages(path, [topic]):
        q = msg.pose.pose.orientation
        yaw = np.arctan2(2 * (q.w * q.z + q.x * q.y), 1 - 2 * (q.y * q.y + q.z * q.z))
        stamps.append(stamp_to_sec(msg.header.stamp))
        poses.append((msg.pose.pose.position.x, msg.pose.pose.position.y, yaw))
    return np.array(stamps), np.array(poses)
