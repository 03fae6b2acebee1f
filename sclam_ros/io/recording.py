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
    messages: dict = field(default_factory=dict)  # topic -> messages read
    frontend: Frontend = None


def iter_outputs(path, params, sink, progress=None, start=None, stop=None):
    """Feed a bag's messages in record order to `sink` (a Frontend or an OnlineCalibrator:
    anything with add_encoder, add_scan and rejections), through the same conversions the
    node uses; yield what each call returns. `start`/`stop`: record-time window (s)."""
    topics = [params.joint_states_topic, params.scan_topic]
    total = sum(bag.topic_info(path).get(t, (None, 0))[1] for t in topics)
    if start is not None or stop is not None:  # a window: estimate its share of the messages
        first, last = bag.time_span(path)
        lo, hi = max(first, start or first), min(last, stop or last)
        total = int(total * max(0.0, hi - lo) / max(last - first, 1e-9))
    messages = bag.iter_messages(path, topics, start, stop)
    for seen, (topic, _, msg) in enumerate(messages, 1):
        if progress is not None and seen % 500 == 0:
            progress(seen, total)
        if topic == params.joint_states_topic:
            try:
                stamp, left, right = joint_state_to_raw(msg, params)
            except MessageRejected as exc:
                if exc.reason not in sink.rejections.counts:
                    log.warning("rejecting %s messages (counted): %s", topic, exc)
                sink.rejections.add(exc.reason)
                continue
            yield sink.add_encoder(stamp, left, right)
        else:
            yield sink.add_scan(laser_scan_to_scan(msg))
    if progress is not None:
        progress(total, total)


def iter_keyframes(path, params, frontend=None, progress=None, start=None, stop=None):
    """Yield keyframes from a bag (or its record-time window [start, stop)) in record order."""
    frontend = frontend or Frontend(params)
    for keyframes in iter_outputs(path, params, frontend, progress, start, stop):
        yield from keyframes
    yield from frontend.flush()


def read_recording(path, params, progress=None, start=None, stop=None) -> Recording:
    frontend = Frontend(params)
    keyframes = list(iter_keyframes(path, params, frontend, progress, start, stop))
    return Recording(keyframes, frontend.rejections, frontend=frontend)


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
