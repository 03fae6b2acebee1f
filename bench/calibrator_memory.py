"""Memory of the online calibrator over hours: --hours of simulated data (10 Hz / 360 beams,
100 Hz encoders) fed to the OnlineCalibrator faster than real time; RSS every simulated minute
must stay flat (the window and its marginalised chunks are bounded).

Run: .venv/bin/python bench/calibrator_memory.py [--hours 1]
"""
import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import scratch_dir, table  # noqa: E402


def rss_mb() -> float:
    with open("/proc/self/status") as fh:
        for line in fh:
            if line.startswith("VmRSS:"):
                return float(line.split()[1]) / 1024.0
    return float("nan")


def memory_run(hours, workdir, scan_rate=10.0, beams=360, encoder_rate=100.0):
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


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--hours", type=float, default=1.0)
    args = parser.parse_args()
    samples = memory_run(args.hours, scratch_dir("sclam_memory_"))
    print(f"memory: {args.hours:g} h of simulated data (10 Hz / 360 beams, 100 Hz encoders) "
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
