"""End to end, as a user runs it: simulate a bag, `sclam calibrate` it, compare with truth."""
import json
import subprocess
import sys

import numpy as np
import pytest

from sclam_ros.cli.main import main
from sclam_ros.core.params import CALIBRATION_KEYS
from sclam_ros.sim import simulate


@pytest.fixture(scope="module", params=["sqlite3", "mcap"])
def recording(request, tmp_path_factory):
    out = tmp_path_factory.mktemp(f"sim_{request.param}") / "bag"
    truth = simulate(out, robot="powerbot", duration=150.0, seed=11, storage=request.param)
    return out, truth


def test_calibrate_recovers_truth_within_sigma(recording, tmp_path, capsys):
    bag, truth = recording
    out_json = tmp_path / "calibration.json"
    rc = main(["calibrate", str(bag), "--params", str(bag / "params.yaml"), "--json", str(out_json),
               "--quiet"])
    assert rc == 0
    result = json.loads(out_json.read_text())
    assert set(result) == set(CALIBRATION_KEYS) | {"sigma", "scans_used", "duration_s", "converged",
                                                   "observable", "warnings", "rejected", "messages",
                                                   "nominal", "frames", "wheel_noise_correction"}
    assert result["converged"] is True
    # A drive that turns both ways determines the base well: the dilution is corrected.
    assert result["wheel_noise_correction"]["applied"] is True
    # A clean recording: nothing to warn about (the map warm-up is counted, not warned).
    assert result["warnings"] == [] and result["rejected"] == {"match_map_warmup": 3}
    assert all(result["observable"].values())
    # 1500 scans at 10 Hz, every third matched (frontend/decimation.py).
    assert result["scans_used"] > 450 and result["duration_s"] == pytest.approx(150, abs=1)
    for key in CALIBRATION_KEYS:
        err = result[key] - truth[key]
        sigma = result["sigma"][key]
        assert np.isfinite(result[key]) and sigma > 0
        assert abs(err) < 4 * sigma, f"{key}: error {err:.5f}, σ {sigma:.5f}"
    # The nominal starting values are 1-4 % off; the estimate must be much closer.
    for key in ("wheel_radius_left", "wheel_radius_right", "wheel_base"):
        assert abs(result[key] - truth[key]) / truth[key] < 0.005, key
    table = capsys.readouterr().out
    assert "wheel_base" in table and "1σ" in table


def test_console_script_runs_and_writes_report(recording, tmp_path):
    bag, _ = recording
    proc = subprocess.run(
        [sys.executable, "-m", "sclam_ros.cli.main", "calibrate", str(bag), "--params",
         str(bag / "params.yaml"), "--report", str(tmp_path), "--quiet"],
        capture_output=True, text=True, timeout=300,
    )
    assert proc.returncode == 0, proc.stderr
    assert (tmp_path / "trajectories.png").stat().st_size > 10_000
    assert (tmp_path / "residuals.png").stat().st_size > 10_000


@pytest.fixture(scope="module")
def short_bag(tmp_path_factory):
    out = tmp_path_factory.mktemp("short") / "bag"
    simulate(out, robot="pioneer", duration=20.0, seed=2)
    return out


def test_wrong_topic_gives_clear_error(short_bag, tmp_path, capsys):
    bag = short_bag
    params = (bag / "params.yaml").read_text().replace("/scan", "/no_such_scan")
    (tmp_path / "p.yaml").write_text(params)
    rc = main(["calibrate", str(bag), "--params", str(tmp_path / "p.yaml"), "--quiet"])
    assert rc == 2
    err = capsys.readouterr().err
    assert "/no_such_scan" in err and "/scan" in err  # names the missing and the available


def test_wrong_joint_names_give_clear_error(short_bag, tmp_path, capsys):
    bag = short_bag
    params = (bag / "params.yaml").read_text().replace(": left_wheel_joint", ": wheel_l")
    (tmp_path / "p.yaml").write_text(params)
    rc = main(["calibrate", str(bag), "--params", str(tmp_path / "p.yaml"), "--quiet"])
    assert rc == 2
    err = capsys.readouterr().err
    assert "scans could be paired" in err
    assert "joint" in err.split("Rejections:")[1]  # says the joints were the problem


def test_bad_params_file_gives_clear_error(tmp_path, capsys):
    (tmp_path / "p.yaml").write_text("sclam:\n  ros__parameters:\n    wheel_base: -1.0\n")
    rc = main(["calibrate", str(tmp_path), "--params", str(tmp_path / "p.yaml")])
    assert rc == 2
    assert "wheel_base must be a number in (0, 20]" in capsys.readouterr().err


def test_missing_bag_gives_clear_error(tmp_path, capsys):
    (tmp_path / "p.yaml").write_text("sclam:\n  ros__parameters:\n    wheel_base: 0.5\n")
    rc = main(["calibrate", str(tmp_path / "nope"), "--params", str(tmp_path / "p.yaml")])
    assert rc == 2
    assert "nope" in capsys.readouterr().err


def test_wheels_left_unconfirmed_are_explained_by_the_matches_not_the_motion(tmp_path, capsys):
    """Outdoors a 5 cm laser has few straight surfaces: most scan matches cannot be
    confirmed, and the wheels, with too few matches to be compared with, keep their nominal
    values. The explanation says so (the drive turns both ways: the motion is not to blame),
    no correction of theirs is reported as if they had been estimated, and a warning says
    that the σ of what was estimated may be too small."""
    bag = tmp_path / "bag"
    simulate(bag, duration=60.0, seed=2, scene="outdoor", range_noise=0.05)
    out_json = tmp_path / "calibration.json"
    rc = main(["calibrate", str(bag), "--params", str(bag / "params.yaml"), "--json",
               str(out_json), "--quiet"])
    assert rc == 0
    result = json.loads(out_json.read_text())
    unobserved = [k for k in CALIBRATION_KEYS[:3] if not result["observable"][k]]
    assert unobserved
    for key in unobserved:
        assert result[key] == result["nominal"][key]
    printed = capsys.readouterr().out
    assert "scan matches could be confirmed" in printed and "lacks the motion" not in printed
    correction = result.get("wheel_noise_correction") or {"shift_percent": {}}
    assert not set(correction["shift_percent"]) & set(unobserved)
    # What was estimated (the laser pose) carries a caution about its σ.
    assert any("σ may be too small" in line for line in result["warnings"])
