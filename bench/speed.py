"""Acceptance 4 of the calibration issue: speed and memory of `sclam calibrate`.

A 10-minute recording (10 Hz scans of 360 beams, 50 Hz encoders): real-time factor
(target ≥ 20×). Time per scan for 1, 5 and 20 minute recordings (must not grow), and the
peak resident memory of each run (one fresh process per recording, so peaks don't mix).
Medians of --repeat runs.

Run: .venv/bin/python bench/speed.py [--repeat 3]
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


def main():
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--minutes", type=float, nargs="*", default=[1, 5, 10, 20])
    args = ap.parse_args()
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
