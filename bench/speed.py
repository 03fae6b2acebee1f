"""Acceptance 4 of the calibration issue: speed and memory of `sclam calibrate`.

A 10-minute recording (10 Hz scans of 360 beams, 50 Hz encoders): real-time factor
(target ≥ 20×). Time per scan for 1, 5 and 20 minute recordings (must not grow), and the
peak resident memory of each run (one fresh process per recording, so peaks don't mix).
Medians of --repeat runs.

--memory: instead, the memory of the online calibrator over hours: --hours of simulated data
(10 Hz / 360 beams, 100 Hz encoders) fed to the OnlineCalibrator faster than real time; RSS
every simulated minute must stay flat (the window and its marginalised chunks are bounded).

Run: .venv/bin/python bench/speed.py [--repeat 3]
     .venv/bin/python bench/speed.py --memory [--hours 1]
"""
import argparse
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
from common import scratch_dir, table

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


def main():
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--minutes", type=float, nargs="*", default=[1, 5, 10, 20])
    ap.add_argument("--memory", action="store_true",
                    help="the online calibrator's memory over --hours instead of the timings")
    ap.add_argument("--hours", type=float, default=1.0, help="--memory: hours of simulated data")
    args = ap.parse_args()
    if args.memory:
        memory_table(args.hours)
        return
    from sclam_ros.sim import simulate

    work = scratch_dir("sclam_speed_")
    rows = []
    for minutes in args.minutes:
        bag = work / f"powerbot_{minutes:g}min"
        simulate(bag, robot="powerbot", duration=60 * minutes, seed=5)
        runs = []
        for _ in range(args.repeat):
            code = CHILD.format(bench=str(Path(__file__).parent), path=str(bag))
            out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
            runs.append(json.loads(out.stdout.strip().splitlines()[-1]))
        med = {k: float(np.median([r[k] for r in runs])) for k in runs[0]}
        total = med["front"] + med["solve"]
        rows.append([f"{minutes:g} min", int(med["scans"]), f"{med['front']:.1f}", f"{med['solve']:.1f}",
                     f"{total:.1f}", f"{med['duration'] / total:.0f}×",
                     f"{1000 * total / med['scans']:.2f}", f"{med['rss']:.0f}"])
        print(rows[-1], flush=True)
    print(f"\nsclam calibrate on simulated PowerBot recordings (median of {args.repeat} runs, "
          f"10 Hz × 360 beams, 50 Hz encoders, this machine: 2 cores):")
    print(table(rows, ["recording", "scans used", "read+match s", "solve s", "total s",
                       "real-time factor", "ms per scan used", "peak RSS MB"]))


if __name__ == "__main__":
    main()
