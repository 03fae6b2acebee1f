"""Bags from other drivers and simulators: other field of view, beam order, encoder units,
record times. The estimate must not depend on our simulator's conventions."""
import math

import numpy as np
import pytest

from sclam_ros.io import bag
from sclam_ros.core.estimator import calibrate_keyframes
from sclam_ros.core.inputs import Scan
from sclam_ros.io.recording import read_recording
from sclam_ros.core.params import CALIBRATION_KEYS, SclamParams
from sclam_ros.sim import simulate


@pytest.fixture(scope="module")
def source(tmp_path_factory):
    out = tmp_path_factory.mktemp("src") / "bag"
    truth = simulate(out, robot="pioneer", duration=120.0, seed=9)
    return out, truth


def rewrite(src, dst, params, fov_deg, reverse, radians, record_delay):
    """A copy of `src` as another driver would have recorded it."""
    tpr = params.ticks_per_revolution
    with bag.BagWriter(dst, storage="mcap") as writer:
        for topic, t, msg in bag.iter_messages(src, ["/joint_states", "/scan"]):
            stamp = msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec
            if topic == "/joint_states":
                pos = np.array(msg.position, float)
                if radians:
                    pos = pos * 2 * math.pi / tpr
                writer.write_joint_state(topic, stamp, list(msg.name), list(pos), record_time_s=t + record_delay)
                continue
            ranges = np.array(msg.ranges, float)
            angles = msg.angle_min + msg.angle_increment * np.arange(len(ranges))
            keep = np.abs(angles) <= math.radians(fov_deg) / 2 + 1e-9
            ranges, angles = ranges[keep], angles[keep]
            increment = msg.angle_increment
            if reverse:  # an upside-down scanner: beams clockwise
                ranges, angles, increment = ranges[::-1], angles[::-1], -increment
            writer.write_scan(topic, Scan(stamp, ranges, float(angles[0]), increment, msg.range_min,
                                          msg.range_max, 0.0, "base_scan"),
                              record_time_s=t + record_delay)


@pytest.mark.parametrize("fov_deg, reverse, radians", [(180, True, True), (270, False, False)])
def test_other_conventions_same_calibration(source, tmp_path, fov_deg, reverse, radians):
    src, truth = source
    params = SclamParams.from_yaml(src / "params.yaml")
    dst = tmp_path / "foreign"
    rewrite(src, dst, params, fov_deg, reverse, radians, record_delay=0.03)
    if radians:
        params.ticks_per_revolution = 0.0
    recording = read_recording(dst, params)
    result = calibrate_keyframes(recording.keyframes, params, recording.rejections)
    for key in CALIBRATION_KEYS:
        assert abs(result.estimate[key] - truth[key]) < 4 * result.sigma[key], key
    assert abs(result.estimate["wheel_base"] / truth["wheel_base"] - 1) < 0.01
