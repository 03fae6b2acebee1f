"""Acceptance 4 of the online node: latency, CPU share, memory, dropped encoder messages.

Latency: a simulated recording is replayed in real time through sclam_node's own
callbacks (SclamNode._on_joint_state / _on_scan, message conversion and publishing
included, no DDS transport), on one thread as rclpy's single-threaded executor runs them,
while the node's window-solver thread (sclam_ros/online/solver_thread.py) runs beside it, as in
the running node. Each message is handed over at its record time (or as soon as the
previous callback is done, if that is later: the wait counts as latency), so GIL and
core sharing between callbacks and solver are in the numbers. Measured, in wall time:
  - scan → keyframe: from a scan's arrival to the end of the callback that turned it into
    a keyframe (the scan is registered in its own callback; the keyframe is finished by
    the encoder callback that reaches its stamp, usually queued behind the registration);
  - scan → estimate update: for the scans whose keyframe asked for a window solve, from
    arrival to the publication of the first ~/wheel_parameters that includes them;
  - encoder → ~/odom: from an encoder message's arrival to the end of its callback
    (~/odom is published inside it, so this is an upper bound).
Dropped encoder messages: arrivals that find 200 (the JointState queue depth) encoder
messages arrived and not yet handled. CPU share: process CPU time (all threads) / duration.

Memory: --hours of simulated data fed straight into the OnlineCalibrator, faster than
real time; RSS sampled every simulated minute must stay flat.

    python bench/node_latency.py                  # both rates, 120 s each; memory over 1 h
    python bench/node_latency.py --hours 0        # skip the memory run
    python bench/node_latency.py --rates 40 --hours 0 --components [--scan-max-beams 0]
"""
from __future__ import annotations

import argparse
import contextlib
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import table  # noqa: E402

os.environ.setdefault("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp")
os.environ.setdefault("ROS_DOMAIN_ID", str(1 + os.getpid() % 200))

JOINT_QUEUE_DEPTH = 200  # the node's JointState subscription depth


def rss_mb() -> float:
    with open("/proc/self/status") as fh:
        for line in fh:
            if line.startswith("VmRSS:"):
                return float(line.split()[1]) / 1024.0
    return float("nan")


class ComponentTimer:
    """Wall time of the node's pieces during a run (--components): each named function is
    wrapped for the run, and the garbage collector's passes are timed by generation."""

    PIECES = (  # (module, attribute path, name in the table)
        ("sclam_ros.frontend.pipeline", "Frontend._register", "scan registration (matcher + point-to-line)"),
        ("sclam_ros.online.window", "OnlineCalibrator.prepare_solve", "solve: build the problem (under the lock)"),
        ("sclam_ros.online.solver_thread", "run_solve", "solve: LM + covariance"),
        ("sclam_ros.online.window", "OnlineCalibrator.marginalise_chunks", "marginalise leaving keyframes"),
    )

    def __init__(self):
        self.seconds = {}
        self._restore = []

    def __enter__(self):
        import gc
        import importlib

        for module_name, path, label in self.PIECES:
            owner = importlib.import_module(module_name)
            *outer, attr = path.split(".")
            for name in outer:
                owner = getattr(owner, name)
            original = getattr(owner, attr)
            setattr(owner, attr, self._timed(original, label))
            self._restore.append((owner, attr, original))
        self._gc_start = None
        gc.callbacks.append(self._on_gc)
        return self

    def __exit__(self, *exc):
        import gc

        gc.callbacks.remove(self._on_gc)
        for owner, attr, original in reversed(self._restore):
            setattr(owner, attr, original)

    def _timed(self, function, label):
        def timed(*args, **kwargs):
            start = time.perf_counter()
            try:
                return function(*args, **kwargs)
            finally:
                self.seconds.setdefault(label, []).append(time.perf_counter() - start)
        return timed

    def _on_gc(self, phase, info):
        if phase == "start":
            self._gc_start = time.perf_counter()
        elif self._gc_start is not None:
            label = f"garbage collection, generation {info['generation']}"
            self.seconds.setdefault(label, []).append(time.perf_counter() - self._gc_start)

    def rows(self):
        return [[label, len(v), f"{1e3 * np.median(v):.1f}", f"{1e3 * np.percentile(v, 90):.1f}",
                 f"{1e3 * np.percentile(v, 99):.1f}", f"{1e3 * np.max(v):.1f}"]
                for label, v in self.seconds.items()]


def replay_through_node(bag, params_file, scan_max_beams=None, timer=None):
    """Real-time replay; per message (is_scan, arrival, finish, frames made, solve asked,
    skipped) and the (wall time, keyframe stamp) of every published estimate. With a
    ComponentTimer, its pieces are timed during the replay."""
    import rclpy

    from sclam_ros.io.bag import iter_messages, topic_info
    from sclam_ros.ros.player import rclpy_class, rosbags_to_rclpy
    from sclam_ros.ros.node import SclamNode
    from sclam_ros.core.params import SclamParams

    params = SclamParams.from_yaml(params_file)
    if scan_max_beams is not None:
        params.scan_max_beams = scan_max_beams
    info = topic_info(bag)
    topics = [params.joint_states_topic, params.scan_topic]
    messages = [(topic, t, rosbags_to_rclpy(msg, rclpy_class(info[topic][0])))
                for topic, t, msg in iter_messages(bag, topics)]
    context = rclpy.Context()
    rclpy.init(context=context)
    try:
        overrides = [rclpy.parameter.Parameter(k, value=v) for k, v in
                     params.to_yaml_dict()["sclam"]["ros__parameters"].items()]
        node = SclamNode(context=context, parameter_overrides=overrides)
        published = []  # (wall time, stamp of the newest keyframe in the solve)
        publish = node._publish_estimate

        def timed_publish(estimate):
            published.append((time.perf_counter(), estimate.stamp))
            publish(estimate)

        node.solver.on_estimate = timed_publish
        # Preallocated: a growing list of tuples would be the bench's own garbage-collector
        # load (a full collection walks every tuple), charged to the node's latency.
        table_ = np.zeros((len(messages), 7))
        with timer or contextlib.nullcontext():
            t_first, wall0 = messages[0][1], time.perf_counter() + 0.5
            cpu0 = time.process_time()
            for row, (topic, t, msg) in enumerate(messages):
                arrival = wall0 + (t - t_first)
                while (now := time.perf_counter()) < arrival:
                    time.sleep(min(arrival - now, 0.002))
                is_scan = topic == params.scan_topic
                frames_before = node.calibrator.frontend._count
                requests_before = node.solver.requests
                skipped_before = node.calibrator.skipped_scans
                (node._on_scan if is_scan else node._on_joint_state)(msg)
                table_[row] = (is_scan, arrival, time.perf_counter(),
                               node.calibrator.frontend._count - frames_before,
                               node.solver.requests > requests_before,
                               node.calibrator.skipped_scans > skipped_before, _stamp(msg))
            time.sleep(1.0)  # let the last solve finish
            cpu = time.process_time() - cpu0
        records = [(bool(r[0]), r[1], r[2], int(r[3]), bool(r[4]), bool(r[5]), r[6]) for r in table_]
        node.destroy_node()
    finally:
        rclpy.try_shutdown(context=context)
    return records, published, cpu


def _stamp(msg) -> float:
    return msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec


def latencies(records, published):
    """scan → keyframe, scan → estimate update, encoder → odom (s); dropped encoders."""
    pending_scans = []  # (arrival, stamp) of matched scans not yet turned into keyframes
    scan_latency, solve_latency, odom_latency = [], [], []
    pub_wall = np.array([w for w, _ in published])
    pub_stamp = np.array([s for _, s in published])
    joint_arrivals = np.array([r[1] for r in records if not r[0]])
    joint_finishes = np.array([r[2] for r in records if not r[0]])
    # Encoder messages arrived but not yet handled when each one arrives.
    waiting = np.searchsorted(joint_arrivals, joint_arrivals, side="right") - np.searchsorted(
        joint_finishes, joint_arrivals, side="right")
    dropped = int(np.sum(waiting > JOINT_QUEUE_DEPTH))
    for is_scan, arrival, finish, frames, asked, skipped, stamp in records:
        if is_scan and not skipped:  # a skipped scan (above 10 Hz) has no estimate of its own
            pending_scans.append((arrival, stamp))
        elif not is_scan:
            odom_latency.append(finish - arrival)
        for _ in range(min(frames, len(pending_scans))):
            scan_arrival, scan_stamp = pending_scans.pop(0)
            scan_latency.append(finish - scan_arrival)
            if asked:
                covering = np.nonzero((pub_stamp >= scan_stamp - 1e-6) & (pub_wall >= finish))[0]
                if len(covering):
                    solve_latency.append(pub_wall[covering[0]] - scan_arrival)
    return (np.array(scan_latency), np.array(solve_latency), np.array(odom_latency), dropped)


def memory_run(hours, workdir, scan_rate, beams, encoder_rate):
    from sclam_ros.io.recording import iter_keyframes
    from sclam_ros.core.params import SclamParams
    from sclam_ros.sim import simulate
    from sclam_ros.online.window import OnlineCalibrator

    bag = workdir / "memory"
    simulate(bag, robot="powerbot", duration=hours * 3600.0, seed=2, scan_rate=scan_rate,
             beams=beams, encoder_rate=encoder_rate, overwrite=True)
    params = SclamParams.from_yaml(bag / "params.yaml")
    calibrator = OnlineCalibrator(params)
    samples, next_minute, first = [], 0.0, None
    for kf in iter_keyframes(bag, params, calibrator.frontend):
        calibrator.add_keyframes([kf])
        first = kf.stamp if first is None else first
        if kf.stamp - first >= next_minute:
            samples.append((next_minute / 60.0, rss_mb(), len(calibrator.window)))
            next_minute += 60.0
    return samples


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--duration", type=float, default=120.0, help="s per latency run")
    parser.add_argument("--hours", type=float, default=1.0, help="simulated hours for the memory run")
    parser.add_argument("--rates", type=float, nargs="+", default=[10.0, 40.0],
                        help="scan rates to run: 10 (360 beams), 40 (1080 beams)")
    parser.add_argument("--scan-max-beams", type=float, default=None,
                        help="override the parameter (default: the recording's params.yaml)")
    parser.add_argument("--components", action="store_true",
                        help="also time the node's pieces (registration, solve, GC) per run")
    args = parser.parse_args()
    from sclam_ros.sim import simulate

    workdir = Path(tempfile.mkdtemp(prefix="sclam_latency_"))
    rows = []
    components = []
    for scan_rate, beams, encoder_rate in ((10.0, 360, 100.0), (40.0, 1080, 100.0)):
        if scan_rate not in args.rates:
            continue
        bag = workdir / f"s{scan_rate:g}_b{beams}"
        simulate(bag, robot="powerbot", duration=args.duration, seed=4, scan_rate=scan_rate,
                 beams=beams, encoder_rate=encoder_rate, overwrite=True)
        timer = ComponentTimer() if args.components else None
        records, published, cpu = replay_through_node(bag, bag / "params.yaml",
                                                      args.scan_max_beams, timer)
        if timer is not None:
            components += [[f"{scan_rate:g} Hz / {beams}"] + row for row in timer.rows()]
        scan, solve, odom, dropped = latencies(records, published)
        period = 1.0 / scan_rate
        skipped = sum(r[5] for r in records)
        ms = lambda x, q: f"{1e3 * np.percentile(x, q):.1f}" if len(x) else "n/a"  # noqa: E731
        p99 = np.percentile(solve, 99)  # the estimate update: the slowest kind of scan
        duration = records[-1][1] - records[0][1]
        rows.append([
            f"{scan_rate:g} Hz / {beams}", f"{encoder_rate:g} Hz", len(scan), skipped,
            ms(scan, 50), ms(scan, 99), len(solve), ms(solve, 50), ms(solve, 99),
            f"{1e3 * period:.0f}",
            "yes" if p99 < period else f"NO (+{1e3 * (p99 - period):.0f} ms)",
            ms(odom, 50), ms(odom, 99), f"{100 * cpu / duration:.0f} %", dropped,
        ])
        print(f"done {scan_rate:g} Hz / {beams} beams", flush=True)
    print(f"\nlatency through sclam_node's callbacks and solver thread, real time, "
          f"{args.duration:.0f} s of simulated PowerBot per row (ms)")
    print(table(rows, ["scans", "encoders", "scans matched", "skipped (>10 Hz)",
                       "scan→keyframe p50", "p99", "solves", "scan→estimate update p50", "p99",
                       "scan period", "update p99 < period",
                       "encoder→odom p50", "p99", "CPU of one core", "encoder msgs dropped"]))
    if components:
        print("\nthe node's pieces during those runs (ms of wall time)")
        print(table(components, ["scans", "piece", "calls", "p50", "p90", "p99", "max"]))
    if args.hours > 0:
        samples = memory_run(args.hours, workdir, 10.0, 360, 100.0)
        print(f"\nmemory: {args.hours:g} h of simulated data (10 Hz / 360 beams, 100 Hz encoders) "
              "fed to the OnlineCalibrator; RSS every simulated minute")
        every = max(1, len(samples) // 12)
        print(table([[f"{m:.0f}", f"{r:.0f}", k] for m, r, k in samples[::every] + samples[-1:]],
                    ["minute", "RSS MB", "window keyframes"]))
        rss = np.array([r for _, r, _ in samples])
        half = len(rss) // 2
        print(f"RSS growth over the second half: {rss[-1] - rss[half]:+.1f} MB "
              f"(first half: {rss[half] - rss[0]:+.1f} MB)")


if __name__ == "__main__":
    main()
