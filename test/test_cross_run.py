"""Cross-run prediction (sclam_ros.diagnosis.cross_run, `sclam diagnose --predict`) on short simulated
recordings of one robot: a clock offset fitted on one drive corrects another drive that has
the same offset, and only that one."""
import json

import pytest

from sclam_ros.cli import main as cli
from sclam_ros.diagnosis import cross_run
from sclam_ros.io.recording import read_recording
from sclam_ros.core.params import SclamParams
from sclam_ros.sim.record import simulate

DURATION = 40.0
OFFSET = 0.02  # s, encoder clock ahead of the laser's


@pytest.fixture(scope="module")
def drives(tmp_path_factory):
    """Two drives (different routes) with the offset, and the second route without it."""
    root = tmp_path_factory.mktemp("cross_run")
    specs = {"a": (1, {"time_offset": OFFSET}), "b": (2, {"time_offset": OFFSET}), "b_clean": (2, None)}
    for name, (seed, effects) in specs.items():
        simulate(root / name, duration=DURATION, seed=seed, effects=effects)
    return root


def _recording(bag):
    params = SclamParams.from_yaml(bag / "params.yaml")
    return read_recording(bag, params).keyframes, params


def test_cli_predict_reports_cross_run_error_lower_with_the_offset(drives, tmp_path):
    out = tmp_path / "diag.json"
    a, b = drives / "a", drives / "b"
    assert cli.main(["diagnose", str(a), "--params", str(a / "params.yaml"), "--effects",
                     "time_offset", "--predict", str(b), "--json", str(out), "--quiet"]) == 0
    report = json.loads(out.read_text())
    assert set(report) >= {"base", "extended", "error_metric", "effects", "unexplained"}
    assert "error_cross_run" in report["error_metric"] and str(b) in report["error_metric"]
    assert [e["name"] for e in report["effects"] if e["selected"]] == ["time_offset"]
    # The same offset is in drive b: carrying it over must explain part of b's disagreement.
    assert report["extended"]["error_cross_run"] < report["base"]["error_cross_run"]
    assert report["extended"]["cross_run_edges"] > 0.8 * DURATION / 0.5  # 0.5 s keyframes


def test_carried_over_offset_is_the_true_one_and_helps_only_where_it_exists(drives):
    a, b, clean = (_recording(drives / n) for n in ("a", "b", "b_clean"))
    _, extended = cross_run.fit_models(*a, ["time_offset"])
    assert extended.values["time_offset"][0, 0] == pytest.approx(OFFSET, rel=0.2)
    with_offset = cross_run.cross_run_errors(*a, *b, ["time_offset"])
    without = cross_run.cross_run_errors(*a, *clean, ["time_offset"])
    assert with_offset["gain"] > 0
    # Same route, no offset: the correction δ·Δω is then an error of its own.
    assert without["gain"] < with_offset["gain"]
