"""Fleet throughput and one long recording in parallel, on Dask distributed (issue 16).

Table 1: `sclam fleet` over --recordings simulated recordings of --duration s (different
seeds, two robots) with 1 and 2 worker processes: wall time including the cluster's start,
recordings per minute, and recorded seconds per wall second.
Table 2: one --long-minute 10 Hz / 360-beam recording: `sclam calibrate` sequential
(--workers 1) and with --workers 2 (time chunks registered in parallel on local processes,
joined in one graph): wall time, real-time factor, and the largest difference of a parameter
from the sequential run in units of its σ.
Wall times are medians of --repeat runs of the command a user types (fresh process each).

--example: instead, the example fleet of docs/fleet.md: two robots, five 60 s recordings
each, two real changes. robot_a's left tyre grows by 2 % before its day 3 (a new tyre);
robot_b's laser is knocked by 1° in yaw before its day 4. Runs `sclam fleet` and
`sclam fleet report` on them (in --out) as a user would and copies the report's figure to
docs/figures/fleet_history.png. The report must flag exactly those two changes.

Run: .venv/bin/python bench/fleet.py [--recordings 8 --duration 120 --long 10 --repeat 3]
     (--recordings 0 skips table 1)
     .venv/bin/python bench/fleet.py --example [--out /tmp/example_fleet]
"""
import argparse
import json
import math
import shutil
import statistics
import subprocess
import time
from pathlib import Path

from common import scratch_dir, table

from sclam_ros.core.params import CALIBRATION_KEYS
from sclam_ros.sim import simulate

DOCS_FIGURE = Path(__file__).resolve().parents[1] / "docs" / "figures" / "fleet_history.png"


def timed(command):
    start = time.perf_counter()
    subprocess.run(command, check=False, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return time.perf_counter() - start


def fleet_table(work, recordings, duration, repeat):
    for i in range(recordings):
        simulate(work / "fleet" / f"robot_{i % 2}" / f"day{i // 2}", duration=duration,
                 seed=100 + i, overwrite=True)
    rows = []
    for workers in (1, 2):
        walls = []
        for _ in range(repeat):
            out = work / f"out_{workers}"
            shutil.rmtree(out, ignore_errors=True)
            walls.append(timed(["sclam", "fleet", str(work / "fleet"), "--out", str(out),
                                "--workers", str(workers), "--quiet"]))
        wall = statistics.median(walls)
        rows.append([workers, f"{recordings} × {duration:.0f} s", f"{wall:.1f}",
                     f"{60 * recordings / wall:.1f}", f"{recordings * duration / wall:.0f}×"])
    return table(rows, ["workers", "recordings", "wall s", "recordings/min", "real time"])


def long_table(work, minutes, repeat):
    bag = work / "long"
    simulate(bag, duration=60.0 * minutes, seed=7, overwrite=True)
    rows, estimates = [], {}
    for label, extra in (("sequential", ["--workers", "1"]), ("--workers 2", ["--workers", "2"])):
        walls = []
        for _ in range(repeat):
            out = work / "long.json"
            walls.append(timed(["sclam", "calibrate", str(bag), "--params", str(bag / "params.yaml"),
                                "--json", str(out), "--quiet", *extra]))
        estimates[label] = json.loads(out.read_text())
        wall = statistics.median(walls)
        rows.append([label, f"{minutes:.0f} min", f"{wall:.1f}", f"{60 * minutes / wall:.0f}×"])
    reference, chunked = estimates["sequential"], estimates["--workers 2"]
    shift = max(abs(chunked[k] - reference[k]) / reference["sigma"][k] for k in CALIBRATION_KEYS)
    rows[0].append("(reference)")
    rows[1].append(f"{shift:.2f}")
    return table(rows, ["run", "recording", "wall s", "real time", "max |Δ|/σ vs sequential"])


def example_fleet(root: Path) -> None:
    """docs/fleet.md's example fleet in `root`, its report, and the report's figure copied
    to the docs."""
    for day in range(1, 6):
        truth = simulate(root / "fleet" / "robot_a" / f"day{day}", duration=60, seed=10 + day,
                         overwrite=True, true_overrides={
                             "wheel_radius_left": 0.1263 * (1.02 if day >= 3 else 1.0)})
        knocked = math.radians(1.0) if day >= 4 else 0.0
        simulate(root / "fleet" / "robot_b" / f"day{day}", duration=60, seed=20 + day,
                 overwrite=True, true_overrides={"laser_yaw": truth["laser_yaw"] + knocked})
    results = root / "results"
    subprocess.run(["sclam", "fleet", str(root / "fleet"), "--out", str(results)], check=True)
    subprocess.run(["sclam", "fleet", "report", str(results)], check=True)
    shutil.copy(results / "history.png", DOCS_FIGURE)
    print(f"figure copied to {DOCS_FIGURE}")


def main():
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--recordings", type=int, default=8)
    ap.add_argument("--duration", type=float, default=120.0)
    ap.add_argument("--long", type=float, default=10.0, help="minutes of the long recording")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--example", action="store_true",
                    help="the example fleet of docs/fleet.md instead of the timings")
    ap.add_argument("--out", default="/tmp/example_fleet", help="--example: where it is written")
    args = ap.parse_args()
    if args.example:
        example_fleet(Path(args.out))
        return
    work = scratch_dir("sclam_fleet_bench_")
    try:
        if args.recordings:
            print(fleet_table(work, args.recordings, args.duration, args.repeat), "\n", flush=True)
        print(long_table(work, args.long, args.repeat))
    finally:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
