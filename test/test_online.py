"""The online calibrator (window.py) offline: `sclam calibrate --track`, the incremental
keyframe merge, and a load change tracked by the sliding window."""
from __future__ import annotations

import csv

import numpy as np
import pytest

from sclam_ros.cli.main import main
from sclam_ros.core.graph import merge_keyframes
from sclam_ros.io.recording import read_recording
from sclam_ros.core.params import CALIBRATION_KEYS, SclamParams
from sclam_ros.sim import simulate
from sclam_ros.io.recording import iter_keyframes
from sclam_ros.online.window import POSE_WINDOW_DISTANCE, KeyframeMerger, OnlineCalibrator

DURATION = 200.0
CHANGE_AT = 100.0  # s after the start
CHANGE = {"left": -0.01, "right": -0.0033}


@pytest.fixture(scope="module")
def load_change(tmp_path_factory):
    """A PowerBot whose radii drop (left −1 %, right −0.33 %) at mid-run, tracked online."""
    out = tmp_path_factory.mktemp("online") / "bag"
    truth = simulate(out, robot="powerbot", duration=DURATION, seed=21,
                     effects={"radius_change_at": (CHANGE_AT, CHANGE["left"], CHANGE["right"])})
    track = out.parent / "track.csv"
    rc = main(["calibrate", str(out), "--params", str(out / "params.yaml"), "--track", str(track),
               "--quiet"])
    assert rc == 0
    with open(track) as fh:
        rows = list(csv.DictReader(fh))
    return out, truth, rows


def test_track_csv_has_the_documented_columns(load_change):
    _, _, rows = load_change
    assert list(rows[0]) == ["t", *CALIBRATION_KEYS, *(f"sigma_{k}" for k in CALIBRATION_KEYS),
                             *(f"observable_{k}" for k in CALIBRATION_KEYS)]
    t = np.array([float(r["t"]) for r in rows])
    assert len(rows) > 100 and np.all(np.diff(t) > 0)
    for row in rows:
        assert all(np.isfinite(float(v)) for v in row.values())
        assert all(float(row[f"sigma_{k}"]) > 0 for k in CALIBRATION_KEYS)


def test_tracked_radii_follow_a_load_change(load_change):
    _, truth, rows = load_change
    t = np.array([float(r["t"]) for r in rows]) - truth["start_time"]
    for key, change in (("wheel_radius_left", CHANGE["left"]), ("wheel_radius_right", CHANGE["right"])):
        old, new = truth[key], truth[key] * (1 + change)
        value = np.array([float(r[key]) for r in rows])
        sigma = np.array([float(r[f"sigma_{key}"]) for r in rows])
        before = (t > CHANGE_AT - 30) & (t < CHANGE_AT)
        # Before the change the windowed estimate agrees with the old truth within its 3σ.
        assert np.all(np.abs(value[before] - old) < 3 * sigma[before]), key
        # Well after the change (the window refilled), the estimate has moved toward the
        # new truth: closer to it than to the old one for the bigger (left) change, and
        # within 3σ of the new one for both.
        after = t > CHANGE_AT + 80
        mean_after = value[after].mean()
        assert abs(mean_after - new) < 3 * sigma[after].mean(), key
        if key == "wheel_radius_left":
            assert abs(mean_after - new) < abs(mean_after - old)


def test_radius_change_detected_after_the_change_only(load_change):
    """The radii window is cut (window.py: change test) once, after the change and within a
    minute of it; before it the window keeps growing past the pose window."""
    bag, truth, _ = load_change
    params = SclamParams.from_yaml(bag / "params.yaml")
    calibrator = OnlineCalibrator(params)
    detected, longest_before = [], 0.0
    for kf in iter_keyframes(bag, params, calibrator.frontend):
        changes = calibrator.radius_changes
        calibrator.add_keyframes([kf])
        t = kf.stamp - truth["start_time"]
        if calibrator.radius_changes > changes:
            detected.append(t)
        if t < CHANGE_AT:
            longest_before = max(longest_before, calibrator.window_length())
    assert len(detected) == 1 and CHANGE_AT < detected[0] < CHANGE_AT + 60, detected
    assert longest_before > 2 * POSE_WINDOW_DISTANCE  # the marginalised part counts


def test_incremental_merge_equals_the_batch_merge(load_change):
    bag, _, _ = load_change
    params = SclamParams.from_yaml(bag / "params.yaml")
    keyframes = read_recording(bag, params).keyframes[:400]
    batch = merge_keyframes(keyframes, params.keyframe_interval)
    merger = KeyframeMerger(params.keyframe_interval)
    online = [m for kf in keyframes for m in merger.add(kf)]
    # The batch merge closes its last partial chunk at the end of the run; online it waits.
    assert len(batch) - 1 <= len(online) <= len(batch)
    for a, b in zip(batch, online):
        assert (a.index, a.stamp, a.laser_from) == (b.index, b.stamp, b.laser_from)
        assert (a.dphi is None) == (b.dphi is None)
        if a.dphi is not None:
            np.testing.assert_allclose(a.dphi, b.dphi)
        if a.laser_motion is not None:
            np.testing.assert_allclose(a.laser_motion, b.laser_motion)
            np.testing.assert_allclose(a.laser_information, b.laser_information)
