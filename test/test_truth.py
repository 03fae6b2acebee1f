"""--truth: the layouts of true values `sclam calibrate` prints beside its estimate."""
import json

import pytest

from sclam_ros.cli.main import main
from sclam_ros.core.params import CALIBRATION_KEYS
from sclam_ros.io.truth import TruthError, read_truth
from sclam_ros.sim import simulate

SHORT = {"r_l": 0.1, "r_r": 0.101, "b": 0.4, "l_x": 0.1, "l_y": 0.0, "l_yaw": 0.01}


def test_reads_simulate_truth_and_short_names_under_true(tmp_path):
    flat = dict(zip(CALIBRATION_KEYS, (0.1, 0.101, 0.4, 0.1, 0.0, 0.01)), robot="x", seed=1)
    (tmp_path / "a.json").write_text(json.dumps(flat))
    (tmp_path / "b.json").write_text(json.dumps({"true": SHORT, "nominal": {"r_l": 0.2}}))
    expected = dict(zip(CALIBRATION_KEYS, (0.1, 0.101, 0.4, 0.1, 0.0, 0.01)))
    assert read_truth(tmp_path / "a.json") == expected
    assert read_truth(tmp_path / "b.json") == expected


@pytest.mark.parametrize("doc, says", [
    ({"true": {k: v for k, v in SHORT.items() if k != "b"}}, "no true value for wheel_base"),
    ({"true": {**SHORT, "b": "wide"}}, "wheel_base must be a finite number"),
    ([1, 2], "expected a JSON object"),
])
def test_unusable_truth_is_one_line_before_reading_the_bag(tmp_path, capsys, doc, says):
    (tmp_path / "t.json").write_text(json.dumps(doc))
    with pytest.raises(TruthError, match=says):
        read_truth(tmp_path / "t.json")
    (tmp_path / "p.yaml").write_text("sclam:\n  ros__parameters:\n    wheel_base: 0.4\n")
    rc = main(["calibrate", str(tmp_path / "no_bag"), "--params", str(tmp_path / "p.yaml"),
               "--truth", str(tmp_path / "t.json"), "--quiet"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and says in err[0], err


def test_calibrate_prints_the_other_layout_beside_the_estimate(tmp_path, capsys):
    bag = tmp_path / "bag"
    truth = simulate(bag, robot="pioneer", duration=30.0, seed=3)
    short = {s: truth[k] for s, k in zip(SHORT, CALIBRATION_KEYS)}
    (tmp_path / "t.json").write_text(json.dumps({"true": short}))
    rc = main(["calibrate", str(bag), "--params", str(bag / "params.yaml"),
               "--truth", str(tmp_path / "t.json"), "--quiet"])
    out = capsys.readouterr().out
    assert rc == 0
    row = next(line for line in out.splitlines() if line.startswith("wheel_base"))
    assert "truth" in out and f"{1000 * truth['wheel_base']:.3f}" in row
