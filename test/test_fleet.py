"""sclam fleet and chunked registration on a real 2-worker Dask LocalCluster.

Recordings are simulated (ground truth known); the corrupt one is a real bag whose storage
file was overwritten with random bytes.
"""
import json
import os
import shutil
import signal
import threading
import time

import numpy as np
import pytest

from sclam_ros.cli.main import main as sclam
from sclam_ros.core.params import CALIBRATION_KEYS
from sclam_ros.sim import simulate

DURATION = 40.0
RADIUS_CHANGE = 1.02  # a new tyre: +2 % left radius on day 3, ~8 combined σ at 40 s


@pytest.fixture(scope="module")
def fleet(tmp_path_factory):
    """robot_a: day1, day2 (same robot), day3 (left tyre changed); robot_b: day1 corrupt."""
    root = tmp_path_factory.mktemp("fleet")
    truth = simulate(root / "robot_a" / "day1", duration=DURATION, seed=1)
    simulate(root / "robot_a" / "day2", duration=DURATION, seed=2)
    changed = {"wheel_radius_left": RADIUS_CHANGE * truth["wheel_radius_left"]}
    simulate(root / "robot_a" / "day3", duration=DURATION, seed=3, true_overrides=changed)
    corrupt = root / "robot_b" / "day1"
    simulate(corrupt, duration=DURATION, seed=4)
    storage = next(corrupt.glob("*.db3"))
    storage.write_bytes(np.random.default_rng(0).bytes(storage.stat().st_size))
    return root


def results_of(out):
    return {json.loads(p.read_text())["bag"]: json.loads(p.read_text())
            for p in (out / "recordings").glob("*.json")}


def test_fleet_corrupt_recording_fails_alone_and_rerun_does_no_work(fleet, tmp_path, capsys):
    out = tmp_path / "results"
    status = sclam(["fleet", str(fleet), "--out", str(out), "--workers", "2", "--quiet"])
    assert status == 1  # one recording failed
    results = results_of(out)
    assert len(results) == 4
    failed = [r for r in results.values() if r["status"] == "failed"]
    assert [r["robot"] for r in failed] == ["robot_b"]
    assert "cannot" in failed[0]["error"] or "corrupt" in failed[0]["error"].lower()
    truth = json.loads((fleet / "robot_a" / "day1" / "truth.json").read_text())
    for result in results.values():
        if result["status"] == "ok":
            assert result["robot"] == "robot_a"
            for key in ("wheel_base", "laser_x"):
                assert abs(result["estimate"][key] - truth[key]) < 4 * result["sigma"][key]
    rows = (out / "results.csv").read_text().splitlines()
    assert len(rows) == 5 and rows[0].startswith("robot,bag,start_time,duration_s,status")
    assert sum(",failed," in row for row in rows) == 1

    stamps = {p: p.stat().st_mtime_ns for p in (out / "recordings").glob("*.json")}
    capsys.readouterr()
    assert sclam(["fleet", str(fleet), "--out", str(out), "--workers", "2", "--quiet"]) == 1
    assert "0 calibrated, 4 unchanged" in capsys.readouterr().out
    assert {p: p.stat().st_mtime_ns for p in stamps} == stamps


def test_fleet_report_flags_the_changed_tyre_only(fleet, tmp_path, capsys):
    out = tmp_path / "results"
    sclam(["fleet", str(fleet / "robot_a"), "--out", str(out), "--workers", "2", "--quiet"])
    capsys.readouterr()
    assert sclam(["fleet", "report", str(out)]) == 0
    printed = capsys.readouterr().out
    changes = (out / "changes.csv").read_text().splitlines()[1:]
    flagged = {(row.split(",")[1], row.split(",")[3].rsplit("/", 1)[-1]) for row in changes}
    assert ("wheel_radius_left", "day3") in flagged, printed
    assert all(bag == "day3" for _, bag in flagged), printed  # nothing changed on day 2
    assert (out / "history.png").stat().st_size > 10_000


def test_fleet_completes_when_a_worker_is_killed(fleet, tmp_path):
    from sclam_ros.fleet.engine import dask_client
    from sclam_ros.fleet.recordings import collect
    from sclam_ros.fleet.runner import run_fleet
    from sclam_ros.fleet.store import ResultStore

    recordings = collect([str(fleet / "robot_a")])
    killed = []

    def kill_a_busy_worker(client):
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and not killed:
            busy = [w for w, keys in client.processing().items() if keys]
            if busy:
                pid = client.run(os.getpid, workers=busy[:1])[busy[0]]
                os.kill(pid, signal.SIGKILL)
                killed.append(pid)
            time.sleep(0.05)

    with dask_client(workers=2, dashboard=False) as client:
        killer = threading.Thread(target=kill_a_busy_worker, args=(client,), daemon=True)
        killer.start()
        summary = run_fleet(client, recordings, ResultStore(tmp_path))
        killer.join()
    assert killed, "no worker was busy: the test did not test anything"
    assert summary.calibrated == 3 and not summary.failed


def test_chunked_registration_matches_sequential(tmp_path):
    """Three time chunks on two workers, joined in one graph: every parameter within 0.3 σ of
    the sequential run, and one keyframe per scan with the chain unbroken at the seams."""
    from sclam_ros.core.estimator import calibrate_keyframes
    from sclam_ros.core.params import SclamParams
    from sclam_ros.fleet.chunked import register_in_chunks
    from sclam_ros.fleet.engine import dask_client
    from sclam_ros.io.recording import read_recording

    bag = tmp_path / "long"
    simulate(bag, duration=120.0, seed=5)
    params = SclamParams.from_yaml(bag / "params.yaml")
    sequential = read_recording(bag, params)
    with dask_client(workers=2, dashboard=False) as client:
        keyframes, rejections = register_in_chunks(client, bag, params, chunks=3)
    assert [kf.stamp for kf in keyframes] == [kf.stamp for kf in sequential.keyframes]
    assert rejections.counts["chunk_boundary_unlinked"] == 0
    assert sum(kf.dphi is None for kf in keyframes) == sum(
        kf.dphi is None for kf in sequential.keyframes)
    reference = calibrate_keyframes(sequential.keyframes, params)
    chunked = calibrate_keyframes(keyframes, params)
    for key in CALIBRATION_KEYS:
        shift = abs(chunked.estimate[key] - reference.estimate[key]) / reference.sigma[key]
        assert shift < 0.3, (key, shift)


def test_fleet_inputs_errors_are_one_line(tmp_path, capsys):
    assert sclam(["fleet", str(tmp_path / "missing"), "--out", str(tmp_path / "o")]) == 2
    assert sclam(["fleet", "report", str(tmp_path)]) == 2
    manifest = tmp_path / "m.csv"
    manifest.write_text("name,path\nx,y\n")
    assert sclam(["fleet", str(manifest), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert err.count("sclam fleet: error:") == 3 and "Traceback" not in err
    assert "lacks column(s) robot, bag" in err
