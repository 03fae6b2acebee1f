"""Live latency of sclam_node over real DDS, beside a bare relay in the same run.

A simulated PowerBot recording (100 Hz encoders; 10 Hz / 360-beam or 40 Hz / 1080-beam laser)
is published in real time on /joint_states and /scan with wall-clock stamps. Four processes,
as on a robot:
  - this driver: publishes, and notes the wall time of every publish;
  - `sclam_node`, started as a user starts it (console script, --params-file);
  - a bare rclpy relay: JointState in → nav_msgs/Odometry out with the same stamp, nothing else
    (the floor: what rclpy and DDS cost on this machine);
  - a listener: notes the wall time at which each /sclam/odom, /relay/odom and
    /sclam/laser_pose message arrives.
Matched by stamp:
  - encoder → odom: from a JointState's publish to the arrival of the odometry with its stamp,
    for sclam_node and for the relay (both go through the same two DDS hops);
  - scan → estimate: from a scan's publish to the arrival of the first ~/laser_pose stamped with
    it (the node stamps an estimate with its newest scan). Estimates come out at about 1 Hz (a
    window solve every 2 keyframes of 0.5 s, scans matched at most every 0.09 s): the figure
    is how late an estimate is, not how often;
  - max backlog: the largest `calibrator_backlog` in /diagnostics (1 Hz) from 5 s after the
    start: messages handed to the calibrator process and not yet taken. Near 0 means it keeps
    up and never queues work.
"answered" counts JointStates whose odometry reached the listener; "node received / published"
is the node's own count (/diagnostics: joint_states_received, odom_published; odom_unanswered_*
says why for the rest), which tells a message the node never got or refused from one DDS lost
on the way out. The machine is named above the table.

Run: .venv/bin/python bench/node_latency.py [--duration 90] [--rates 10 40]
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import scratch_dir, table  # noqa: E402

os.environ.setdefault("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp")
os.environ.setdefault("ROS_DOMAIN_ID", str(1 + os.getpid() % 200))

JOINT_QUEUE_DEPTH = 200  # as sclam_node's JointState subscription
LISTEN_TAIL_S = 5.0  # the listener listens this long after the last message sent


def _stamp_key(stamp) -> int:
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def relay_main() -> None:
    """The bare relay: JointState → Odometry, same stamp, in its own process."""
    import rclpy
    from nav_msgs.msg import Odometry
    from sensor_msgs.msg import JointState

    rclpy.init()
    node = rclpy.create_node("relay")
    publisher = node.create_publisher(Odometry, "/relay/odom", 50)

    def relay(msg):
        out = Odometry()
        out.header.stamp = msg.header.stamp
        out.header.frame_id = "odom"
        publisher.publish(out)

    node.create_subscription(JointState, "/joint_states", relay, JOINT_QUEUE_DEPTH)
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, Exception):  # noqa: BLE001 - ended by the driver
        pass


def listen_main(out: str, seconds: float) -> None:
    """Arrival wall times of the node's and the relay's outputs, by stamp, to `out` (JSON):
    until `seconds` have passed, or LISTEN_TAIL_S after the driver has created `out`.done
    (its last message sent), so that a slow start never cuts off the last answers."""
    import rclpy
    from geometry_msgs.msg import PoseWithCovarianceStamped
    from nav_msgs.msg import Odometry
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

    rclpy.init()
    node = rclpy.create_node("latency_listener")
    arrivals = {"/sclam/odom": {}, "/relay/odom": {}, "/sclam/laser_pose": {}}
    backlog = []  # (arrival, calibrator_backlog) of every /diagnostics message (1 Hz)
    last_values = {}  # the node's newest /diagnostics key/values: its counts by reason

    def note(topic):
        def callback(msg):
            arrivals[topic].setdefault(_stamp_key(msg.header.stamp), time.time())
        return callback

    node.create_subscription(Odometry, "/sclam/odom", note("/sclam/odom"), 1000)
    node.create_subscription(Odometry, "/relay/odom", note("/relay/odom"), 1000)
    latched = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
    node.create_subscription(PoseWithCovarianceStamped, "/sclam/laser_pose",
                             note("/sclam/laser_pose"), latched)
    from diagnostic_msgs.msg import DiagnosticArray

    def diagnostics(msg):
        for status in msg.status:
            values = {kv.key: kv.value for kv in status.values}
            if "calibrator_backlog" in values:
                backlog.append((time.time(), int(values["calibrator_backlog"])))
                last_values.clear()
                last_values.update(values)

    node.create_subscription(DiagnosticArray, "/diagnostics", diagnostics, 10)
    end = time.monotonic() + seconds
    done = Path(out + ".done")
    while time.monotonic() < end:
        rclpy.spin_once(node, timeout_sec=0.1)
        if done.exists():
            end = min(end, done.stat().st_mtime - time.time() + time.monotonic() + LISTEN_TAIL_S)
    result = {t: list(a.items()) for t, a in arrivals.items()}
    Path(out).write_text(json.dumps({**result, "backlog": backlog, "diagnostics": last_values}))


def machine() -> str:
    model = "unknown CPU"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return f"{os.cpu_count()} cores, {model}, {platform.system()} {platform.release()}"


def _messages(bag, params):
    """(record time, topic, rclpy message) of the recording, in record order."""
    from sensor_msgs.msg import JointState, LaserScan

    from sclam_ros.io import bag as bag_io

    out = []
    for topic, record_time, msg in bag_io.iter_messages(bag, [params.joint_states_topic,
                                                              params.scan_topic]):
        if topic == params.joint_states_topic:
            ros = JointState(name=list(msg.name), position=list(msg.position))
        else:
            ros = LaserScan(angle_min=msg.angle_min, angle_max=msg.angle_max,
                            angle_increment=msg.angle_increment, time_increment=msg.time_increment,
                            scan_time=msg.scan_time, range_min=msg.range_min,
                            range_max=msg.range_max, ranges=msg.ranges.tolist())
        ros.header.frame_id = msg.header.frame_id
        out.append((record_time, topic, ros))
    return out


def _wait_for_subscribers(publishers, counts, timeout=30.0):
    end = time.monotonic() + timeout
    while any(p.get_subscription_count() < n for p, n in zip(publishers, counts)):
        if time.monotonic() > end:
            raise RuntimeError("the node, relay or listener did not subscribe in time")
        time.sleep(0.05)


def run_row(bag, seconds, workdir):
    """Publish `bag` live; (published {topic: {stamp: wall}}, arrivals {topic: {stamp: wall}})."""
    import rclpy
    from rclpy.time import Time
    from sensor_msgs.msg import JointState, LaserScan

    from sclam_ros.core.params import SclamParams

    params = SclamParams.from_yaml(bag / "params.yaml")
    messages = _messages(bag, params)
    arrivals_file = workdir / f"{bag.name}_arrivals.json"
    me = [sys.executable, str(Path(__file__).resolve())]
    children = [
        subprocess.Popen(["sclam_node", "--ros-args", "--params-file", str(bag / "params.yaml"),
                          "-p", f"calibration_file:={workdir / 'calibration.yaml'}"],
                         stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL),
        subprocess.Popen(me + ["relay"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL),
    ]
    listen_for = seconds + 60.0  # at most: start-up and the tail included
    listener = subprocess.Popen(me + ["listen", str(arrivals_file), str(listen_for)])
    rclpy.init()
    node = rclpy.create_node("latency_driver")
    joints = node.create_publisher(JointState, params.joint_states_topic, JOINT_QUEUE_DEPTH)
    from rclpy.qos import qos_profile_sensor_data

    scans = node.create_publisher(LaserScan, params.scan_topic, qos_profile_sensor_data)
    published = {params.joint_states_topic: {}, params.scan_topic: {}}
    try:
        _wait_for_subscribers([joints, scans], [2, 1])
        time.sleep(3.0)  # the node's calibrator process and the listener's subscriptions
        first = messages[0][0]
        start = time.time()
        for record_time, topic, msg in messages:
            if record_time - first > seconds:
                break
            due = start + (record_time - first)
            delay = due - time.time()
            if delay > 0:
                time.sleep(delay)
            msg.header.stamp = Time(nanoseconds=int(due * 1e9)).to_msg()
            published[topic][_stamp_key(msg.header.stamp)] = time.time()
            (joints if topic == params.joint_states_topic else scans).publish(msg)
        Path(f"{arrivals_file}.done").touch()
        listener.wait(timeout=listen_for + 30.0)
    finally:
        node.destroy_node()
        rclpy.shutdown()
        for child in children:
            child.terminate()
        for child in children:
            child.wait(timeout=30)
    raw = json.loads(arrivals_file.read_text())
    backlog = raw.pop("backlog")
    diagnostics = raw.pop("diagnostics")
    arrivals = {t: {int(k): v for k, v in a} for t, a in raw.items()}
    # Steady state: from 5 s after the first message (the calibrator process may still be
    # importing its libraries when the first messages arrive; they wait in its inbox).
    start = min(published[params.joint_states_topic].values()) + 5.0
    backlog = [b for t, b in backlog if t > start]
    return published, arrivals, backlog, diagnostics, params


def latencies(sent: dict, received: dict, tolerance_ns: int = 0) -> np.ndarray:
    """Arrival − publish of every message that arrived, matched by stamp (within
    `tolerance_ns`: the node's estimate stamps went through a float of seconds)."""
    if not tolerance_ns:
        return np.array([received[k] - sent[k] for k in sent if k in received])
    keys = np.array(sorted(sent))
    out = []
    for key, arrival in received.items():
        i = int(np.clip(np.searchsorted(keys, key), 1, len(keys) - 1))
        nearest = keys[i - 1] if abs(keys[i - 1] - key) < abs(keys[i] - key) else keys[i]
        if abs(int(nearest) - key) <= tolerance_ns:
            out.append(arrival - sent[int(nearest)])
    return np.array(out)


def ms(values, q) -> str:
    return f"{1e3 * np.percentile(values, q):.1f}" if len(values) else "n/a"


def main():
    if len(sys.argv) > 1 and sys.argv[1] == "relay":
        return relay_main()
    if len(sys.argv) > 1 and sys.argv[1] == "listen":
        return listen_main(sys.argv[2], float(sys.argv[3]))
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--duration", type=float, default=90.0, help="s published per row")
    parser.add_argument("--rates", type=float, nargs="+", default=[10.0, 40.0],
                        help="scan rates: 10 (360 beams) and/or 40 (1080 beams)")
    args = parser.parse_args()
    from sclam_ros.sim import simulate

    workdir = scratch_dir("sclam_latency_")
    rows = []
    for scan_rate, beams in ((10.0, 360), (40.0, 1080)):
        if scan_rate not in args.rates:
            continue
        bag = workdir / f"s{scan_rate:g}_b{beams}"
        simulate(bag, robot="powerbot", duration=args.duration + 5.0, seed=4, scan_rate=scan_rate,
                 beams=beams, encoder_rate=100.0, overwrite=True)
        published, arrivals, backlog, diagnostics, params = run_row(bag, args.duration, workdir)
        counts = {k: v for k, v in diagnostics.items()
                  if k.startswith(("rejected_", "odom_")) or k.endswith("_received")}
        print(f"{scan_rate:g} Hz: the node's last /diagnostics counts: {counts}", flush=True)
        joint_sent = published[params.joint_states_topic]
        # Which JointStates (in the order sent) got no ~/odom to the listener: at the
        # start or the end points at the bench's windows, scattered at the node or DDS.
        for topic in ("/sclam/odom", "/relay/odom"):
            missing = [i for i, key in enumerate(sorted(joint_sent)) if key not in arrivals[topic]]
            if missing:
                print(f"{scan_rate:g} Hz: {len(missing)} JointStates without {topic}, "
                      f"at #{missing[:20]} of {len(joint_sent)}", flush=True)
        node = latencies(joint_sent, arrivals["/sclam/odom"])
        relay = latencies(joint_sent, arrivals["/relay/odom"])
        estimate = latencies(published[params.scan_topic], arrivals["/sclam/laser_pose"], 1000)
        period = 1e3 / scan_rate
        rows.append([f"{scan_rate:g} Hz / {beams}", len(joint_sent),
                     f"{len(node)} / {len(relay)}",
                     f"{diagnostics.get('joint_states_received', '?')} / "
                     f"{diagnostics.get('odom_published', '?')}",
                     ms(relay, 50), ms(node, 50), f"{1e3 * (np.percentile(node, 50) - np.percentile(relay, 50)):+.1f}",
                     ms(relay, 99), ms(node, 99), f"{1e3 * (np.percentile(node, 99) - np.percentile(relay, 99)):+.1f}",
                     ms(node, 100), f"{len(estimate) / args.duration:.1f}", ms(estimate, 50),
                     ms(estimate, 99), f"{period:.0f}", max(backlog, default="n/a")])
        print(f"done {scan_rate:g} Hz / {beams} beams", flush=True)
    print(f"\nmachine: {machine()}")
    print(f"live over DDS (Fast DDS), {args.duration:.0f} s per row, 100 Hz encoders; ms")
    print(table(rows, ["laser", "JointStates", "answered node / relay",
                       "node received / published",
                       "relay p50", "node p50", "Δ p50", "relay p99", "node p99", "Δ p99",
                       "node max", "estimates/s", "scan→estimate p50", "p99", "scan period",
                       "max backlog"]))


if __name__ == "__main__":
    main()
