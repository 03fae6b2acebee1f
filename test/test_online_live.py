"""Acceptance 2 of the online node: live equals offline.

A simulated bag played by `sclam play --clock` into a running `sclam_node` (the console
script with --params-file and use_sim_time, over real DDS) ends at the same wheel
parameters as `sclam calibrate --track` on the same bag.
"""
from __future__ import annotations

import csv
import os
import signal
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest

os.environ.setdefault("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp")
os.environ["ROS_DOMAIN_ID"] = str(1 + (os.getpid() + 101) % 200)

import rclpy  # noqa: E402
from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy  # noqa: E402
from std_msgs.msg import Float64MultiArray  # noqa: E402

import polling  # noqa: E402
from sclam_ros.io.bag import topic_info  # noqa: E402
from sclam_ros.cli.main import main  # noqa: E402
from sclam_ros.core.params import ODOMETRY_KEYS  # noqa: E402
from sclam_ros.sim import simulate  # noqa: E402

VENV_BIN = Path(sys.executable).parent
TIMEOUT = 120.0


def wait_for(condition, timeout=TIMEOUT, what="condition"):
    polling.wait_for(condition, timeout, what, interval=0.01)


def test_live_node_ends_where_the_offline_track_ends(tmp_path):
    bag = tmp_path / "bag"
    simulate(bag, robot="powerbot", duration=60.0, seed=8)
    track = tmp_path / "track.csv"
    assert main(["calibrate", str(bag), "--params", str(bag / "params.yaml"), "--track",
                 str(track), "--quiet"]) == 0
    with open(track) as fh:
        offline = list(csv.DictReader(fh))[-1]
    counts = {topic: n for topic, (_, n) in topic_info(bag).items()}

    context = rclpy.Context()
    rclpy.init(context=context)
    executor = SingleThreadedExecutor(context=context)
    tester = rclpy.create_node("live_vs_offline", context=context)
    executor.add_node(tester)
    lock, wheels, diagnostics = threading.Lock(), [], []

    def on_wheels(msg):
        with lock:
            wheels.append(list(msg.data))

    def on_diagnostics(msg):
        with lock:
            diagnostics.append({kv.key: kv.value for s in msg.status for kv in s.values})

    latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
    tester.create_subscription(Float64MultiArray, "/sclam/wheel_parameters", on_wheels, latched)
    tester.create_subscription(DiagnosticArray, "/diagnostics", on_diagnostics, 10)
    thread = threading.Thread(target=executor.spin, daemon=True)
    thread.start()
    node = subprocess.Popen(
        [str(VENV_BIN / "sclam_node"), "--ros-args", "--params-file", str(bag / "params.yaml"),
         "-p", "use_sim_time:=true"],
        cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
    )
    play = None
    try:
        wait_for(lambda: tester.count_subscribers("/scan") >= 1
                 and tester.count_subscribers("/joint_states") >= 1
                 or node.poll() is not None, what="sclam_node's subscriptions")
        assert node.poll() is None, node.stdout.read()
        play = subprocess.run(
            [str(VENV_BIN / "sclam"), "play", str(bag), "--rate", "3", "--clock",
             "--topics", "/joint_states", "/scan", "--wait-for-subscribers", "20"],
            cwd=tmp_path, capture_output=True, text=True, timeout=TIMEOUT,
        )
        assert play.returncode == 0, play.stdout + play.stderr

        def node_done():
            with lock:
                last = diagnostics[-3:]
            # Nothing new over three diagnostics (1 Hz, wall clock): the node is idle.
            keys = ("joint_states_received", "scans_received", "solves")
            # ... and the calibrator process has taken everything handed to it.
            return len(last) == 3 and all(
                d.get(k) == last[0].get(k) for d in last for k in keys) and all(
                d.get("calibrator_backlog") == "0" for d in last)

        wait_for(node_done, what="sclam_node to process the whole bag")
        with lock:
            received = {"/scan": int(diagnostics[-1]["scans_received"]),
                        "/joint_states": int(diagnostics[-1]["joint_states_received"])}
            live = wheels[-1]
            final_diagnostics = diagnostics[-1]
    finally:
        node.send_signal(signal.SIGINT)
        try:
            node.wait(30)
        except subprocess.TimeoutExpired:
            node.kill()
        executor.shutdown()
        tester.destroy_node()
        rclpy.try_shutdown(context=context)
    # Scans go over best-effort QoS: a loaded machine drops a few (measured: 16 of 600 on
    # two busy cores at --rate 3); the estimate must not care.
    for topic, n in received.items():
        assert n >= 0.9 * counts[topic], (topic, n, counts[topic])
    # A clean simulated drive: the matcher keeps (nearly) every scan, live as offline.
    # (It had lost 30 of 600 when seeded with a first, wild wheel-base estimate.)
    lost = int(final_diagnostics.get("rejected_registration_poor_overlap", 0))
    assert lost < 0.01 * counts["/scan"], final_diagnostics
    for i, key in enumerate(ODOMETRY_KEYS):
        sigma = float(offline[f"sigma_{key}"])
        assert live[3 + i] == pytest.approx(sigma, rel=0.3), f"{key}: node diagnostics " + "; ".join(
            f"{k}={v}" for k, v in final_diagnostics.items())
        assert abs(live[i] - float(offline[key])) < sigma, (
            f"{key}: live {live[i]:.6f}, offline {float(offline[key]):.6f}, σ {sigma:.6f}")
