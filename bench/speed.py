"""Speed of `sclam calibrate`, each figure against its floor in the same run (issue 62).

Default: for each --minutes recording (simulated PowerBot, 10 Hz scans of 360 beams, 50 Hz
encoders, seed --seed):
  1. where the sequential calibration's time goes, by stage, as shares of its wall time
     (stage_profile.profile: sampled), beside the floor (stage_profile.floor: reading
     every input message + KISS-ICP alone on the scans the calibration registers);
  2. the command a user types, sequential (--workers 1), automatic (the default) and forced
     onto two processes (--workers 2): wall time (interpreter start included), real-time
     factor, ratio to the floor divided over the processes it used, and the largest
     difference of a parameter from the sequential run in units of its σ;
  3. with --crossover, where parallel chunks start to pay: --workers 1 against --workers 2
     on short recordings of two seeds each (the threshold of fleet/workers.py,
     docs/decisions/parallel.md).
Wall times are medians of --repeat runs, each a fresh process; the floor's too.

--lengths: instead, the cost per scan for 1, 5, 10 and 20 minute recordings (must not grow)
and each run's peak resident memory (one fresh process per recording, so peaks don't mix).

--memory: instead, the memory of the online calibrator over hours: --hours of simulated data
(10 Hz / 360 beams, 100 Hz encoders) fed to the OnlineCalibrator faster than real time; RSS
every simulated minute must stay flat (the window and its marginalised chunks are bounded).

Run: .venv/bin/python bench/speed.py [--minutes 5 10] [--repeat 3] [--crossover]
     .venv/bin/python bench/speed.py --lengths [--repeat 3]
     .venv/bin/python bench/speed.py --memory [--hours 1]
"""
import argparse
import json
import os
import re
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
from common import scratch_dir, table
from stage_profile import ORDER, floor, profile

from sclam_ros.core.params import CALIBRATION_KEYS

CHILD = r"""
import json, sys, time, resource
sys.path.insert(0, {bench!r})
from sclam_ros.core.params import SclamParams
from sclam_ros.io.recording import read_recording
from sclam_ros.core.estimator import calibrate_keyframes
path = {path!r}
params = SclamParams.from_yaml(path + "/params.yaml")
t0 = time.perf_counter()
rec = read_recording(path, params)
t1 = time.perf_counter()
res = calibrate_keyframes(rec.keyframes, params, rec.rejections)
t2 = time.perf_counter()
print(json.dumps(dict(front=t1 - t0, solve=t2 - t1, scans=res.scans_used, duration=res.duration_s,
                      rss=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024)))
"""
MODES = (("sequential", "1"), ("auto", "auto"), ("forced 2", "2"))


def rss_mb() -> float:
    with open("/proc/self/status") as fh:
        for line in fh:
            if line.startswith("VmRSS:"):
                return float(line.split()[1]) / 1024.0
    return float("nan")


def memory_run(hours, workdir, scan_rate=10.0, beams=360, encoder_rate=100.0):
    """(simulated minute, RSS MB, window keyframes) every simulated minute of the online
    calibrator fed `hours` of a simulated recording."""
    from sclam_ros.core.params import SclamParams
    from sclam_ros.io.recording import iter_keyframes
    from sclam_ros.online.calibrator import OnlineCalibrator
    from sclam_ros.sim import simulate

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


def memory_table(hours):
    samples = memory_run(hours, scratch_dir("sclam_memory_"))
    print(f"memory: {hours:g} h of simulated data (10 Hz / 360 beams, 100 Hz encoders) "
          "fed to the OnlineCalibrator; RSS every simulated minute")
    every = max(1, len(samples) // 12)
    print(table([[f"{m:.0f}", f"{r:.0f}", k] for m, r, k in samples[::every] + samples[-1:]],
                ["minute", "RSS MB", "window keyframes"]))
    rss = np.array([r for _, r, _ in samples])
    half = len(rss) // 2
    print(f"RSS growth over the second half: {rss[-1] - rss[half]:+.1f} MB "
          f"(first half: {rss[half] - rss[0]:+.1f} MB)")


def lengths_table(minutes_list, repeat):
    from sclam_ros.sim import simulate

    work = scratch_dir("sclam_speed_")
    rows = []
    for minutes in minutes_list:
        bag = work / f"powerbot_{minutes:g}min"
        simulate(bag, robot="powerbot", duration=60 * minutes, seed=5)
        runs = []
        for _ in range(repeat):
            code = CHILD.format(bench=str(Path(__file__).parent), path=str(bag))
            out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
            runs.append(json.loads(out.stdout.strip().splitlines()[-1]))
        med = {k: float(np.median([r[k] for r in runs])) for k in runs[0]}
        total = med["front"] + med["solve"]
        rows.append([f"{minutes:g} min", int(med["scans"]), f"{med['front']:.1f}", f"{med['solve']:.1f}",
                     f"{total:.1f}", f"{med['duration'] / total:.0f}×",
                     f"{1000 * total / med['scans']:.2f}", f"{med['rss']:.0f}"])
        print(rows[-1], flush=True)
    print(f"\nsclam calibrate on simulated PowerBot recordings (median of {repeat} runs, "
          f"10 Hz × 360 beams, 50 Hz encoders, this machine: {os.cpu_count()} cores):")
    print(table(rows, ["recording", "scans used", "read+match s", "solve s", "total s",
                       "real-time factor", "ms per scan used", "peak RSS MB"]))


def calibrate(bag, workers, out):
    """(wall s, the --json result, the workers it chose) of `sclam calibrate` as a user
    types it."""
    start = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "sclam_ros.cli.main", "calibrate", str(bag),
                           "--params", str(bag / "params.yaml"), "--json", str(out), "--quiet",
                           "--workers", workers], capture_output=True, text=True, check=True)
    wall = time.perf_counter() - start
    chose = re.search(r"registering in (\d+) parallel chunks", done.stderr)
    return wall, json.loads(Path(out).read_text()), int(chose.group(1)) if chose else 1


def largest_shift(result, reference):
    return max(abs(result[k] - reference[k]) / reference["sigma"][k] for k in CALIBRATION_KEYS)


def recording(work, minutes, seed):
    from sclam_ros.sim import simulate

    bag = work / f"powerbot_{minutes:g}min_{seed}"
    if not bag.exists():
        simulate(bag, robot="powerbot", duration=60 * minutes, seed=seed, scan_rate=10,
                 beams=360, encoder_rate=50, overwrite=True)
    return bag


def speed_tables(work, minutes_list, seed, repeat):
    """The profile table and the speed-against-floor table, as printed text."""
    profile_rows, speed_rows = {stage: [] for stage in ORDER}, []
    walls, floors = [], []
    for minutes in minutes_list:
        bag = recording(work, minutes, seed)
        floors_run = [floor(bag) for _ in range(repeat)]
        base = {k: statistics.median(f[k] for f in floors_run)
                for k in ("reading", "conversion", "kiss_icp", "total")}
        base["scans"] = floors_run[0]["scans"]
        floors.append(base)
        sampled = profile(bag)
        walls.append(sampled["wall"])
        for stage in ORDER:
            profile_rows[stage].append(f"{sampled[stage]:.2f} ({100 * sampled[stage] / sampled['wall']:.0f} %)")
        reference = None
        for label, workers in MODES:
            runs = [calibrate(bag, workers, work / f"{label}.json") for _ in range(repeat)]
            wall = statistics.median(r[0] for r in runs)
            result, used = runs[-1][1], runs[-1][2]
            reference = reference or result
            over = base["total"] / used
            speed_rows.append([f"{minutes:g} min", f"{label} ({used} process{'es' if used > 1 else ''})",
                               f"{wall:.1f}", f"{60 * minutes / wall:.0f}×", f"{over:.1f}",
                               f"{wall / over:.2f}", "(reference)" if label == "sequential"
                               else f"{largest_shift(result, reference):.3f}"])
            print(speed_rows[-1], flush=True)
    header = ["stage"] + [f"{m:g} min: s (share)" for m in minutes_list]
    rows = [[stage, *profile_rows[stage]] for stage in ORDER]
    rows.append(["total (sampled run's wall)", *(f"{w:.2f}" for w in walls)])
    rows.append(["floor: reading every input message", *(f"{f['reading']:.2f}" for f in floors)])
    rows.append(["floor: scans → points (registered ones)", *(f"{f['conversion']:.2f}" for f in floors)])
    rows.append(["floor: KISS-ICP alone on the registered scans",
                 *(f"{f['kiss_icp']:.2f} ({f['scans']} scans)" for f in floors)])
    rows.append(["floor: total", *(f"{f['total']:.2f}" for f in floors)])
    speed = table(speed_rows, ["recording", "sclam calibrate", "wall s", "real time",
                               "floor ÷ processes s", "× floor", "max |Δ|/σ vs sequential"])
    return table(rows, header), speed


def crossover_table(work, durations, seeds, repeat):
    """--workers 1 against --workers 2 on short recordings: where parallel starts to pay."""
    rows, pays = [], []
    for seconds in durations:
        row, ratios = [f"{seconds:g} s"], []
        for seed in seeds:
            bag = recording(work, seconds / 60.0, seed)
            walls = {}
            for workers in ("1", "2"):
                walls[workers] = statistics.median(
                    calibrate(bag, workers, work / "crossover.json")[0] for _ in range(repeat))
            ratios.append(walls["2"] / walls["1"])
            row.append(f"{walls['1']:.2f} / {walls['2']:.2f} ({ratios[-1]:.2f})")
        rows.append(row)
        pays.append(max(ratios) < 1.0)
        print(rows[-1], flush=True)
    # The shortest length from which two processes were faster on every seed, there and
    # at every longer length measured.
    from_s = next((d for i, d in enumerate(durations) if all(pays[i:])), None)
    return (table(rows, ["recording"] + [f"seed {s}: --workers 1 / 2 s (ratio)" for s in seeds])
            + f"\nparallel paid from: {'not within these lengths' if from_s is None else f'{from_s:g} s'}")


def main():
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--minutes", type=float, nargs="*", default=[5, 10])
    ap.add_argument("--seed", type=int, default=11)
    ap.add_argument("--crossover", action="store_true",
                    help="also --workers 1 against 2 on --short recordings of --crossover-seeds")
    ap.add_argument("--short", type=float, nargs="*", default=[40, 60, 90, 120, 180],
                    help="s: the recordings of --crossover (two chunks need 40 s)")
    ap.add_argument("--crossover-seeds", type=int, nargs="*", default=[21, 22])
    ap.add_argument("--lengths", action="store_true",
                    help="the cost per scan over --minutes (default 1 5 10 20) instead")
    ap.add_argument("--memory", action="store_true",
                    help="the online calibrator's memory over --hours instead of the timings")
    ap.add_argument("--hours", type=float, default=1.0, help="--memory: hours of simulated data")
    args = ap.parse_args()
    if args.memory:
        memory_table(args.hours)
        return
    if args.lengths:
        lengths_table(args.minutes if "--minutes" in sys.argv else [1, 5, 10, 20], args.repeat)
        return
    work = scratch_dir("sclam_speed_")
    profiled, speed = speed_tables(work, args.minutes, args.seed, args.repeat)
    print(f"\nWhere `sclam calibrate --workers 1` spends its time (one sampled run; simulated "
          f"PowerBot, 10 Hz × 360 beams, 50 Hz encoders, seed {args.seed}; {os.cpu_count()} "
          "cores), and the floor (median of the runs):")
    print(profiled)
    print(f"\n`sclam calibrate` against its floor (median of {args.repeat} runs each):")
    print(speed)
    if args.crossover:
        print("\nWhere parallel chunks start to pay (median of "
              f"{args.repeat} runs each; wall s, ratio < 1: parallel faster):")
        print(crossover_table(work, args.short, args.crossover_seeds, args.repeat))


if __name__ == "__main__":
    main()
