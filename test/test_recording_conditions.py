"""The simulator's recording conditions (sim/conditions.py) change how the recording is
written, not what the robot did; and the diagnosis's whiteness test allows the lag-1
correlation every chained graph has, not more."""
from __future__ import annotations

import math

import numpy as np
import pytest

from sclam_ros.diagnosis.structure import ljung_box
from sclam_ros.io.bag import iter_messages
from sclam_ros.sim import simulate
from sclam_ros.sim.conditions import RecordingConditions


def _scans(path):
    return [m for _, _, m in iter_messages(path, ["/scan"])]


def _stamp(msg):
    return msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec


def test_conditions_change_the_writing_not_the_drive(tmp_path):
    plain = simulate(tmp_path / "plain", robot="pioneer", duration=4.0, seed=7)
    made = simulate(tmp_path / "made", robot="pioneer", duration=4.0, seed=7,
                    effects={"scan_motion": 1.0},
                    conditions=RecordingConditions(scan_phase=0.02, scan_stamp_jitter=0.003,
                                                   sweep_stated=False, no_return="nan",
                                                   ticks_per_revolution=500))
    a, b = _scans(tmp_path / "plain"), _scans(tmp_path / "made")
    start = plain["start_time"]
    # The first scan is taken scan_phase after the first encoder sample, the rest on the
    # scan rate's grid; each stamp is off that grid by the jitter (σ 3 ms), in order.
    grid = start + 0.02 + 0.1 * np.arange(len(b))
    offsets = np.array([_stamp(m) for m in b]) - grid
    assert 0.001 < np.std(offsets) < 0.006 and np.all(np.diff([_stamp(m) for m in b]) > 0)
    assert _stamp(a[0]) == pytest.approx(start + 0.013, abs=1e-6)
    # A sweep the driver does not state: time_increment 0 while the scan is distorted.
    assert all(m.time_increment == 0.0 for m in b)
    # No return written as NaN, where the plain recording has inf.
    assert any(math.isinf(r) for m in a for r in m.ranges)
    assert any(math.isnan(r) for m in b for r in m.ranges)
    assert not any(math.isinf(r) for m in b for r in m.ranges)
    assert made["ticks_per_revolution"] == 500 and made["conditions"]["no_return"] == "nan"
    assert made["wheel_base"] == plain["wheel_base"]


def test_simulate_command_line_takes_the_conditions(tmp_path):
    import json

    from sclam_ros.cli import main as cli

    out = tmp_path / "bag"
    assert cli.main(["simulate", str(out), "--robot", "pioneer", "--duration", "3", "--quiet",
                     "--no-return", "zero", "--scan-phase", "0.02", "--scan-stamp-jitter", "0.002",
                     "--ticks-per-revolution", "500", "--slip-noise", "0"]) == 0
    truth = json.loads((out / "truth.json").read_text())
    assert truth["conditions"]["no_return"] == "zero" and truth["ticks_per_revolution"] == 500
    assert truth["conditions"]["scan_phase"] == 0.02
    assert any(r == 0.0 for m in _scans(out) for r in m.ranges)
    assert cli.main(["simulate", str(tmp_path / "bad"), "--duration", "3", "--quiet",
                     "--scan-stamp-jitter", "-1"]) == 2


def test_no_return_encodings():
    ranges = np.array([1.0, np.inf, 2.0])
    for encoding, value in (("zero", 0.0), ("above_max", 21.0)):
        out = RecordingConditions(no_return=encoding).encode_no_return(ranges, 20.0)
        assert out.tolist() == [1.0, value, 2.0]
    with pytest.raises(ValueError, match="no_return"):
        RecordingConditions(no_return="minus_one")


def test_whiteness_from_lag_two_allows_an_ma1_series_and_finds_longer_memory():
    rng = np.random.default_rng(3)
    n = 2000
    e = rng.standard_normal(n + 1)
    ma1 = e[1:] - 0.6 * e[:-1]  # consecutive matches sharing a scan: lag-1 only
    assert ljung_box(ma1, 10)[1] < 1e-6  # white-noise test: "structure"
    assert ljung_box(ma1, 10, first=2)[1] > 0.01
    ar1 = np.zeros(n)
    for i in range(1, n):  # a slowly varying error: memory at every lag
        ar1[i] = 0.5 * ar1[i - 1] + e[i]
    assert ljung_box(ar1, 10, first=2)[1] < 1e-6


def test_whiteness_is_not_decided_by_one_stretch_of_bad_matches():
    # White residuals of 200 edges with 25 consecutive bad matches of alternating sign
    # (a featureless stretch): no memory outside that stretch, and no structure to report.
    # A slow error of the same size over the whole run is reported.
    rng = np.random.default_rng(5)
    white = rng.standard_normal(200)
    burst = white.copy()
    burst[50:75] += 8.0 * np.where(np.arange(25) % 2, 1.0, -1.0) * rng.uniform(0.5, 1.5, 25)
    values = burst - burst.mean()
    rho2 = np.dot(values[:-2], values[2:]) / np.dot(values, values)
    assert rho2 > 0.3  # what the values' autocorrelation shows
    assert ljung_box(burst, 10, first=2)[1] > 0.01
    slow = white + 1.0 * np.sin(np.arange(200) / 8.0)
    assert ljung_box(slow, 10, first=2)[1] < 1e-4
