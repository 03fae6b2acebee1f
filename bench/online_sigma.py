"""Is the σ the online calibrator publishes honest? Its estimates against the simulator's truth.

The node (sclam_node, and `sclam calibrate --track`) publishes the calibration of its
sliding window with a σ per parameter. Here --seeds simulated recordings without any
change of the robot (PowerBot, office, --duration s) go through the node's calibrator in
record order (cli.calibrate.track), and each published estimate after --settle s is
compared with the truth. Per parameter: RMS of error/σ over the seeds' last estimates
(1 when σ is honest; each seed's one number), the same over every CHECKPOINT s from
--settle on (the estimates of one run are correlated in time, so this pools fewer
independent numbers than it has), and the mean error/σ (a bias σ does not cover). A
parameter the window did not determine is published at its nominal value and prior σ
and is left out. Last, the batch solve's variance factors on the same recordings: the
window is solved with the stated noise model, which they rescale.

Run: .venv/bin/python bench/online_sigma.py [--seeds 10] [--duration 300] [--settle 120] [--jobs 2]
"""
from __future__ import annotations

import argparse
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import scratch_dir, table  # noqa: E402

CHECKPOINT = 30.0  # s between the estimates pooled over a run


def _run(job):
    """(z at the checkpoints (k, 6), observable (k, 6)) of one seed."""
    seed, duration, settle, workdir = job
    from sclam_ros.cli.calibrate import track
    from sclam_ros.core.params import CALIBRATION_KEYS, SclamParams
    from sclam_ros.sim import simulate

    bag = Path(workdir) / f"seed{seed}"
    truth = simulate(bag, duration=duration, seed=seed, overwrite=True)
    params = SclamParams.from_yaml(bag / "params.yaml")
    rows, _, _ = track(bag, params)
    # The batch solve of the same recording: its variance components say by how much the
    # stated noise model the window is solved with is off.
    from sclam_ros.core.estimator import calibrate_keyframes
    from sclam_ros.io.recording import read_recording

    recording = read_recording(bag, params)
    scales = calibrate_keyframes(recording.keyframes, params, recording.rejections).variance_scales
    rows = np.array(rows, float)
    stamps = rows[:, 0] - rows[0, 0]
    n = len(CALIBRATION_KEYS)
    values, sigma, observable = rows[:, 1:1 + n], rows[:, 1 + n:1 + 2 * n], rows[:, 1 + 2 * n:] > 0.5
    z = (values - np.array([truth[k] for k in CALIBRATION_KEYS])) / sigma
    # the last estimate published before each checkpoint, and the run's last one
    picks = [int(np.searchsorted(stamps, t, side="right")) - 1
             for t in np.arange(settle, stamps[-1], CHECKPOINT)] + [len(stamps) - 1]
    picks = sorted(set(p for p in picks if p >= 0 and stamps[p] >= settle))
    return z[picks], observable[picks], scales


def main():
    from sclam_ros.core.params import CALIBRATION_KEYS

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--duration", type=float, default=300.0)
    ap.add_argument("--settle", type=float, default=120.0)
    ap.add_argument("--jobs", type=int, default=2)
    args = ap.parse_args()
    work = scratch_dir("sclam_online_sigma_")
    with ProcessPoolExecutor(args.jobs) as pool:
        runs = list(pool.map(_run, [(s, args.duration, args.settle, work) for s in range(1, args.seeds + 1)]))
    rows = []
    for i, key in enumerate(CALIBRATION_KEYS):
        last = np.array([z[-1, i] for z, o, _ in runs if o[-1, i]])
        pooled = np.concatenate([z[o[:, i], i] for z, o, _ in runs])
        rows.append([key, f"{np.sqrt(np.mean(last ** 2)):.2f}" if len(last) else "–", len(last),
                     f"{np.sqrt(np.mean(pooled ** 2)):.2f}" if len(pooled) else "–", len(pooled),
                     f"{np.mean(pooled):+.2f}" if len(pooled) else "–"])
    print(f"PowerBot, office, {args.seeds} seeds × {args.duration:.0f} s, no change of the robot; "
          f"estimates from {args.settle:.0f} s on, every {CHECKPOINT:.0f} s")
    print(table(rows, ["parameter", "RMS err/σ, last estimate", "seeds", "RMS err/σ, checkpoints",
                       "estimates", "mean err/σ"]))
    groups = sorted({g for _, _, scales in runs for g in scales})
    print("the batch solve's variance factors on the same recordings (median, range): " + "; ".join(
        f"{g} {np.median([sc[g] for *_, sc in runs]):.2f} "
        f"({min(sc[g] for *_, sc in runs):.2f}-{max(sc[g] for *_, sc in runs):.2f})" for g in groups))


if __name__ == "__main__":
    main()
