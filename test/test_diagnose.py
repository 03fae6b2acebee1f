"""sclam diagnose on short simulated recordings: the injected library effect is selected
and estimated within 20 %, the held-out error drops; with no effect nothing is selected."""
import json

import pytest

from sclam_ros.cli import main as cli
from sclam_ros.diagnosis.diagnose import diagnose_keyframes
from sclam_ros.io.recording import read_recording
from sclam_ros.core.params import CALIBRATION_KEYS, SclamParams
from sclam_ros.sim.record import simulate

DURATION = 90.0


def _bag(tmp_path_factory, name, effects):
    out = tmp_path_factory.mktemp("diag") / name
    simulate(out, duration=DURATION, seed=1, effects=effects)
    return out


def _effect(report, name):
    return next(e for e in report["effects"] if e["name"] == name)


def test_cli_selects_time_offset(tmp_path_factory, tmp_path):
    bag = _bag(tmp_path_factory, "offset", {"time_offset": 0.02})
    out = tmp_path / "diag.json"
    assert cli.main([
        "diagnose", str(bag), "--params", str(bag / "params.yaml"), "--json", str(out),
        "--report", str(tmp_path / "report"), "--quiet",
    ]) == 0
    report = json.loads(out.read_text())
    assert set(report) == {"base", "extended", "error_metric", "effects", "unexplained",
                           "unexplained_cause", "not_separable", "calibration_shift_sigma", "timing_noise_s",
                           "scan_matcher_structure",
                           "warnings"}
    for model in ("base", "extended"):
        assert set(report[model]["params"]) == set(CALIBRATION_KEYS)
        assert set(report[model]["residual_rms"]) == {"odometry", "laser"}
    for e in report["effects"]:
        assert set(e) >= {"name", "selected", "value", "sigma", "evidence"}
    for u in report["unexplained"]:
        assert set(u) == {"component", "regressor", "strength"}
    assert [e["name"] for e in report["effects"] if e["selected"]] == ["time_offset"]
    assert _effect(report, "time_offset")["value"] == pytest.approx(0.02, rel=0.2)
    assert report["extended"]["error"] < report["base"]["error"]
    assert list((tmp_path / "report").glob("*.png"))


def test_selects_lateral_slip(tmp_path_factory):
    bag = _bag(tmp_path_factory, "slip", {"lateral_slip": 0.05})
    params = SclamParams.from_yaml(bag / "params.yaml")
    keyframes = read_recording(bag, params, keep_scan_points=True).keyframes
    report = diagnose_keyframes(keyframes, params).report
    assert [e["name"] for e in report["effects"] if e["selected"]] == ["lateral_slip"]
    assert _effect(report, "lateral_slip")["value"] == pytest.approx(0.05, rel=0.2)
    assert report["extended"]["error"] < report["base"]["error"]
    assert report["unexplained"] == []


def test_selects_nothing_without_effect(tmp_path_factory):
    bag = _bag(tmp_path_factory, "plain", None)
    params = SclamParams.from_yaml(bag / "params.yaml")
    keyframes = read_recording(bag, params, keep_scan_points=True).keyframes
    report = diagnose_keyframes(keyframes, params).report
    assert not [e["name"] for e in report["effects"] if e["selected"]]
    assert report["extended"]["error"] == report["base"]["error"]
    # Nothing depends on any regressor, and the residuals have no memory beyond the lag-1
    # correlation that neighbouring edges sharing a pose or a scan have by construction.
    assert report["unexplained"] == []
