"""One recording registered in time chunks on local processes (fleet/processes.py), chosen
by `sclam calibrate`'s default --workers auto, against the sequential run."""
import json
import logging

import pytest

from sclam_ros.cli.main import main
from sclam_ros.core.params import CALIBRATION_KEYS
from sclam_ros.fleet.engine import default_workers
from sclam_ros.fleet.workers import WorkersConfig
from sclam_ros.sim import simulate

THRESHOLD = WorkersConfig().parallel_from_s


def _calibrate(bag, out, caplog, *extra):
    caplog.set_level(logging.INFO, logger="sclam")
    caplog.clear()
    assert main(["calibrate", str(bag), "--params", str(bag / "params.yaml"), "--json",
                 str(out), "--quiet", *extra]) == 0
    return json.loads(out.read_text()), caplog.text


def test_a_short_recording_is_registered_sequentially(tmp_path, caplog):
    bag = tmp_path / "short"
    simulate(bag, duration=THRESHOLD - 20.0, seed=3)
    _, log = _calibrate(bag, tmp_path / "short.json", caplog)
    assert "registering sequentially" in log and "parallel chunks pay from" in log


@pytest.fixture(scope="module")
def long_bag(tmp_path_factory):
    bag = tmp_path_factory.mktemp("long") / "bag"
    simulate(bag, duration=THRESHOLD + 60.0, seed=4)
    return bag


@pytest.mark.skipif(default_workers() < 2, reason="parallel chunks need two cores")
def test_a_long_recording_is_registered_in_parallel_and_agrees_with_sequential(
        long_bag, tmp_path, caplog):
    """The automatic choice registers on every core; the parameters agree with the
    sequential run's within a fraction of σ, and the counts of messages and rejections,
    and the warnings, are the same."""
    bag = long_bag
    auto, log = _calibrate(bag, tmp_path / "auto.json", caplog)
    assert f"registering in {min(default_workers(), 6)} parallel chunks" in log
    sequential, log = _calibrate(bag, tmp_path / "sequential.json", caplog, "--workers", "1")
    assert "registering sequentially (--workers 1)" in log
    for key in CALIBRATION_KEYS:
        shift = abs(auto[key] - sequential[key]) / sequential["sigma"][key]
        assert shift < 0.2, (key, shift)
    assert auto["scans_used"] == sequential["scans_used"]
    assert auto["messages"] == sequential["messages"]
    assert auto["rejected"] == sequential["rejected"]
    assert auto["warnings"] == sequential["warnings"]


def test_an_error_in_a_chunk_is_the_one_line_error_of_a_sequential_run(long_bag, tmp_path,
                                                                      capsys):
    params = tmp_path / "params.yaml"
    params.write_text((long_bag / "params.yaml").read_text().replace("/scan", "/laser"))
    assert main(["calibrate", str(long_bag), "--params", str(params), "--quiet",
                 "--workers", "2"]) == 2
    err = capsys.readouterr().err
    assert "error: topic(s) /laser not in bag" in err and "Traceback" not in err
