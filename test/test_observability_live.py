"""Acceptance (issue 13): never publish what the data did not observe.

A simulated PowerBot drives 60 s straight down the office corridor, then figure-eights and
spins at its end (sim motion "straight_then_turns"). Fed to a running sclam_node over real
DDS: after the straight minute the wheel base and the laser's x and y are at their nominal
values in everything the node publishes and saves, flagged unobservable, and ~/odom
integrates the nominal base; after the turns they are estimated, near the simulator's truth.
The same offline: `sclam calibrate --track` on the straight minute alone and on the whole drive.
"""
from __future__ import annotations

import csv

import numpy as np
import pytest

from test_node import Feeder, Graph, diagnostics_values, start_node, wait_for, wait_until_settled

from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402
from geometry_msgs.msg import PoseWithCovarianceStamped  # noqa: E402
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy  # noqa: E402
from std_msgs.msg import Float64MultiArray  # noqa: E402
from std_srvs.srv import Trigger  # noqa: E402

from sclam_ros.cli.main import main  # noqa: E402
from sclam_ros.core.config import GraphConfig  # noqa: E402
from sclam_ros.core.params import CALIBRATION_KEYS, ODOMETRY_KEYS, SclamParams  # noqa: E402
from sclam_ros.io.bag import iter_messages, topic_info  # noqa: E402
from sclam_ros.ros.player import rclpy_class, rosbags_to_rclpy  # noqa: E402
from sclam_ros.sim import simulate  # noqa: E402
from sclam_ros.sim.record import START_TIME  # noqa: E402

pytestmark = pytest.mark.heavy

STRAIGHT_S = 60.0
TOTAL_S = 120.0  # the straight leg ends at ≈ 68 s; then ~50 s of figure-eights and spins
UNOBSERVED = ("wheel_base", "laser_x", "laser_y")
OBSERVED_WHEN_STRAIGHT = ("wheel_radius_left", "wheel_radius_right", "laser_yaw")
SIGMAS = 4.0  # "close to the truth": within this many of the reported σ


@pytest.fixture(scope="module")
def drives(tmp_path_factory):
    root = tmp_path_factory.mktemp("observability")
    full, straight = root / "full", root / "straight"
    truth = simulate(full, robot="powerbot", duration=TOTAL_S, seed=6, motion="straight_then_turns")
    # The same first minute alone (same seed, same route): for the offline --track check.
    simulate(straight, robot="powerbot", duration=STRAIGHT_S, seed=6, motion="straight")
    return full, straight, truth


def _rclpy_messages(path, params):
    info = topic_info(path)
    topics = [params.joint_states_topic, params.scan_topic]
    return [(topic, stamp, rosbags_to_rclpy(msg, rclpy_class(info[topic][0])))
            for topic, stamp, msg in iter_messages(path, topics)]


def _track(bag, out):
    assert main(["calibrate", str(bag), "--params", str(bag / "params.yaml"), "--track",
                 str(out), "--quiet"]) == 0
    with open(out) as fh:
        return list(csv.DictReader(fh))


def test_track_keeps_unobserved_parameters_at_nominal(drives, tmp_path):
    full, straight, truth = drives
    nominal = SclamParams.from_yaml(straight / "params.yaml").calibration()
    rows = _track(straight, tmp_path / "straight.csv")
    assert [c for c in rows[0] if c.startswith("observable_")] == [
        f"observable_{k}" for k in CALIBRATION_KEYS]
    for row in rows:
        for key in UNOBSERVED:
            assert row[f"observable_{key}"] == "0" and float(row[key]) == pytest.approx(nominal[key])
    for key in OBSERVED_WHEN_STRAIGHT:
        assert rows[-1][f"observable_{key}"] == "1", key
    last = _track(full, tmp_path / "full.csv")[-1]
    for key in CALIBRATION_KEYS:
        assert last[f"observable_{key}"] == "1", key
        assert abs(float(last[key]) - truth[key]) < SIGMAS * float(last[f"sigma_{key}"]), key


def test_node_publishes_saves_and_integrates_only_what_it_observed(drives, tmp_path):
    full, _, truth = drives
    params = SclamParams.from_yaml(full / "params.yaml")
    nominal = params.calibration()
    messages = _rclpy_messages(full, params)
    cut = START_TIME + STRAIGHT_S
    first = [(t, m) for t, stamp, m in messages if stamp < cut]
    rest = [(t, m) for t, stamp, m in messages if stamp >= cut]
    saved = tmp_path / "calibration.yaml"

    graph = Graph()
    try:
        node = start_node(graph, params, calibration_file=str(saved))
        latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)
        graph.subscribe(Float64MultiArray, "/sclam/wheel_parameters", latched)
        graph.subscribe(PoseWithCovarianceStamped, "/sclam/laser_pose", latched)
        graph.subscribe(DiagnosticArray, "/diagnostics")
        feeder = Feeder(graph, node, params)

        # --- 60 s straight ------------------------------------------------------------
        feeder.feed(first)
        wait_for(lambda: node.estimates > 0, what="a first estimate")
        wait_until_settled(node)
        wheels, laser, diagnostics = _published(graph, node)
        values, sigmas, observable = np.reshape(wheels.data, (3, 3))
        for i, key in enumerate(ODOMETRY_KEYS):
            assert observable[i] == (0.0 if key in UNOBSERVED else 1.0), key
        assert values[2] == nominal["wheel_base"]
        assert values[0] != nominal["wheel_radius_left"]  # the radii are estimated
        assert laser.pose.pose.position.x == nominal["laser_x"]
        assert laser.pose.pose.position.y == nominal["laser_y"]
        cov = np.reshape(laser.pose.covariance, (6, 6))
        prior_xy = GraphConfig().prior_sigma_laser_xy
        assert cov[0, 0] == pytest.approx(prior_xy**2)  # the flag: prior variance
        assert cov[1, 1] == pytest.approx(prior_xy**2)
        for key in CALIBRATION_KEYS:
            expected = "false" if key in UNOBSERVED else "true"
            assert diagnostics[f"{key}_observable"] == expected, key
        for key in UNOBSERVED:
            assert float(diagnostics[key]) == pytest.approx(nominal[key], abs=1e-6)
        assert "nan" not in " ".join(diagnostics.values()).lower(), diagnostics
        # ~/odom integrates what the node would publish: the nominal base.
        k, _ = node._odometry_calibration()
        assert k[2] == nominal["wheel_base"]

        response = graph.call(Trigger, "/sclam/save_calibration", Trigger.Request())
        assert response.success and all(key in response.message for key in UNOBSERVED)
        written = SclamParams.from_yaml(saved).calibration()
        for key in UNOBSERVED:
            assert written[key] == nominal[key], key
        assert written["wheel_radius_left"] != nominal["wheel_radius_left"]
        assert "wheel_base" in saved.read_text().split("sclam:")[0]  # named in the header

        # --- then the turns -----------------------------------------------------------
        feeder.feed(rest)
        wait_until_settled(node)
        wheels, laser, diagnostics = _published(graph, node)
        values, sigmas, observable = np.reshape(wheels.data, (3, 3))
        assert list(observable) == [1.0, 1.0, 1.0]
        for i, key in enumerate(ODOMETRY_KEYS):
            assert abs(values[i] - truth[key]) < SIGMAS * sigmas[i], (key, values[i], sigmas[i])
        cov = np.reshape(laser.pose.covariance, (6, 6))
        for slot, key in ((0, "laser_x"), (1, "laser_y")):
            value = getattr(laser.pose.pose.position, key[-1])
            assert abs(value - truth[key]) < SIGMAS * np.sqrt(cov[slot, slot]), (key, value)
        assert all(diagnostics[f"{key}_observable"] == "true" for key in CALIBRATION_KEYS)
        assert node._odometry_calibration()[0][2] == pytest.approx(float(values[2]))
        response = graph.call(Trigger, "/sclam/save_calibration", Trigger.Request())
        assert response.success and "not observed" not in response.message
        written = SclamParams.from_yaml(saved).calibration()
        estimate = node.calibrator.estimate
        for key in UNOBSERVED:
            assert written[key] == pytest.approx(estimate.values[key]) and written[key] != nominal[key]
    finally:
        graph.close()


def _published(graph, node):
    """The latest ~/wheel_parameters and ~/laser_pose (once they show the node's newest
    estimate) and a /diagnostics status sent after them."""
    estimate = node.calibrator.estimate
    wait_for(lambda: graph.messages("/sclam/wheel_parameters") and list(
        graph.messages("/sclam/wheel_parameters")[-1].data[:3])
        == [estimate.values[k] for k in ODOMETRY_KEYS], what="the newest wheel parameters")
    wait_for(lambda: graph.messages("/sclam/laser_pose") and graph.messages(
        "/sclam/laser_pose")[-1].pose.pose.position.x == estimate.values["laser_x"],
        what="the newest laser pose")
    start = len(graph.messages("/diagnostics"))
    wait_for(lambda: len(graph.messages("/diagnostics")) > start, what="diagnostics")
    return (graph.messages("/sclam/wheel_parameters")[-1], graph.messages("/sclam/laser_pose")[-1],
            diagnostics_values(graph.messages("/diagnostics")[-1]))
