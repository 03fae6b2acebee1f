"""online/process.py: the calibrator in a child process, fed as the node feeds it (no DDS).

The same messages go to an in-process OnlineCalibrator and to the child; both must land on the
simulator's truth, and the child's answer must be the in-process one (the same calls in the
same order; only the timing of window solves may differ, which moves the estimate by a small
fraction of σ). Commands and a dying child are checked as the node sees them.
"""
import os
import signal
import time

import numpy as np
import pytest

from sclam_ros.core.params import CALIBRATION_KEYS, SclamParams
from sclam_ros.io import bag
from sclam_ros.io.messages import joint_state_to_raw, laser_scan_to_scan
from sclam_ros.online.process import CalibratorProcess
from sclam_ros.online.calibrator import OnlineCalibrator
from sclam_ros.sim import simulate

import polling


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    out = tmp_path_factory.mktemp("process") / "bag"
    truth = simulate(out, duration=60.0, seed=8)
    params = SclamParams.from_yaml(out / "params.yaml")
    messages = []
    for topic, _, msg in bag.iter_messages(out, [params.joint_states_topic, params.scan_topic]):
        if topic == params.joint_states_topic:
            messages.append(("encoder", joint_state_to_raw(msg, params)))
        else:
            messages.append(("scan", laser_scan_to_scan(msg)))
    return params, messages, truth


def feed(target, messages):
    for kind, data in messages:
        if kind == "encoder":
            target.add_encoder(*data)
        else:
            target.add_scan(data)


def settle(process, quiet=1.0):
    polling.wait_for(lambda: process.backlog == 0 and process.handled > 0, 60, "the child")
    seen = [process.status, time.monotonic()]

    def quiet_for():
        if process.status is not seen[0]:
            seen[:] = [process.status, time.monotonic()]
        return time.monotonic() - seen[1] > quiet

    polling.wait_for(quiet_for, 60, "the child's last solve")


def test_child_estimates_what_the_in_process_calibrator_estimates(recording):
    params, messages, truth = recording
    local = OnlineCalibrator(params)
    feed(local, messages)
    estimates = []
    process = CalibratorProcess(params, on_estimate=estimates.append)
    try:
        feed(process, messages)
        settle(process)
        assert estimates and process.estimate is estimates[-1]
        for key in CALIBRATION_KEYS:
            sigma = local.estimate.sigma[key]
            assert abs(process.estimate.values[key] - truth[key]) < 4 * sigma, key
            assert abs(process.estimate.values[key] - local.estimate.values[key]) < 0.3 * sigma, key
        assert process.rejections.counts == local.rejections.counts
        assert process.status.window_keyframes == len(local.window)
    finally:
        process.stop()


def test_commands_apply_in_order_and_reset_shows_nominal_at_once(recording):
    params, messages, _ = recording
    process = CalibratorProcess(params)
    try:
        feed(process, messages[: len(messages) // 2])
        process.set_window_distance(7.0)
        settle(process)
        assert process.estimate is not None and process.status.window_distance == 7.0
        process.reset_calibration()
        assert process.estimate is None  # no wait: the old estimate is never shown again
        np.testing.assert_array_equal(process.calibration, process.status.nominal)
        settle(process)
        assert process.estimate is None and process.status.window_keyframes == 0
        assert process.status.window_distance == 7.0
    finally:
        process.stop()


def test_a_dead_child_is_reported_and_input_is_not_piled_up(recording):
    params, messages, _ = recording
    errors = []
    process = CalibratorProcess(params, on_error=errors.append)
    try:
        feed(process, messages[:50])
        settle(process)
        os.kill(process._process.pid, signal.SIGKILL)
        polling.wait_for(lambda: process.failure is not None, 10, "the failure to be noticed")
        assert not process.alive and errors and "calibrator process ended" in errors[0]
        sent = process.sent
        feed(process, messages[50:60])
        assert process.sent == sent and process.dropped == 10
    finally:
        process.stop()


def test_the_child_ends_when_the_node_is_killed(tmp_path):
    """A node killed outright (SIGKILL: no "stop", no atexit) must not leave its calibrator
    process running: the child notices its parent is gone and ends."""
    import subprocess
    import sys

    script = tmp_path / "node_like.py"
    script.write_text(
        "import sys, time\n"
        "from sclam_ros.core.params import SclamParams\n"
        "from sclam_ros.online.process import CalibratorProcess\n"
        "if __name__ == '__main__':\n"
        "    calibrator = CalibratorProcess(SclamParams())\n"
        "    print(calibrator._process.pid, flush=True)\n"
        "    time.sleep(120)\n")
    parent = subprocess.Popen([sys.executable, str(script)], stdout=subprocess.PIPE, text=True)
    try:
        child = int(parent.stdout.readline())
        assert _alive(child)
        parent.kill()
        parent.wait(10)
        polling.wait_for(lambda: not _alive(child), 10.0,
                         f"calibrator process {child} to end after its parent was killed")
    finally:
        parent.kill()


def _alive(pid: int) -> bool:
    """True while `pid` exists and is not a zombie (an ended child not yet reaped)."""
    try:
        with open(f"/proc/{pid}/stat") as stat:
            return stat.read().split(")")[-1].split()[0] != "Z"
    except FileNotFoundError:
        return False
