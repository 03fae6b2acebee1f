"""Load changes tracked by the online calibrator (the code path of `sclam calibrate --track`
and of sclam_node), against the simulator's truth.

Scenarios (PowerBot in the office, default window_distance 100 m, --seeds seeds each):
  step 1 % both      both radii −1 % at 240 s (a load put on the robot), 360 s run
  step 0.5 % left    the left radius −0.5 % at 240 s (a soft tyre), 360 s run
  step back          both radii +1 % at 240 s (the load taken off), 360 s run
  ramp 1 % / 5 min   both radii −1 % linearly from 180 s to 480 s, 600 s run
  two steps          both −1 % at 240 s and −1 % more at 300 s, 420 s run
  clean 10 min       no change, 600 s run (false alarms)
Per scenario, worst over its seeds (errors against the truth at each estimate's time):
  detection delay: from the (first) change to the first detected radius change;
  radius error from 30 s / 60 s after the (last) change (ramp: after its start), %;
  wheel base and laser error from SETTLE s on (the window has filled), changes included;
  false alarms per hour: detections before any change (all of the clean run);
  radius |err|/σ: each published radius' error over its published σ, RMS and worst over
  the seeds, in the 30 s after the (first) change (while the estimate lags the new radii)
  and from 30 s after the last change on (clean run: from SETTLE s on); and how long after
  the (first) change both are first within 2σ of the truth.

Run: .venv/bin/python bench/load_change.py [--seeds 5] [--jobs 2] [--scenarios ...]
     [--set SECTION.FIELD=VALUE ...]   (the calibrator's OnlineConfig, e.g. window.distance=10)
"""
from __future__ import annotations

import argparse
import math
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import configured, scratch_dir, table  # noqa: E402

from sclam_ros.online.config import OnlineConfig  # noqa: E402

SETTLE = 120.0  # s: the first estimates (window filling) are not judged

# name: (duration s, time of the first change s or None, time of the last change s, effects)
SCENARIOS = {
    "step 1 % both": (360.0, 240.0, 240.0, {"radius_change_at": {"time": 240.0, "left": -0.01,
                                                                  "right": -0.01}}),
    "step 0.5 % left": (360.0, 240.0, 240.0, {"radius_change_at": {"time": 240.0, "left": -0.005,
                                                                    "right": 0.0}}),
    "step back": (360.0, 240.0, 240.0, {"radius_change_at": {"time": 240.0, "left": 0.01,
                                                              "right": 0.01}}),
    "ramp 1 % / 5 min": (600.0, 180.0, 180.0, {"radius_ramp": {"time": 180.0, "duration": 300.0,
                                                                "left": -0.01, "right": -0.01}}),
    "two steps": (420.0, 240.0, 300.0, {"radius_change_at": {
        "time": 240.0, "left": -0.01, "right": -0.01, "then_after": 60.0, "then_left": -0.01,
        "then_right": -0.01}}),
    "clean 10 min": (600.0, None, None, {}),
}
RADII = ("wheel_radius_left", "wheel_radius_right")


def run_one(job):
    """Simulate one scenario/seed and track it; the row of numbers for the table."""
    name, seed, workdir, config = job
    from sclam_ros.core.params import CALIBRATION_KEYS, SclamParams
    from sclam_ros.io.recording import iter_outputs
    from sclam_ros.online.calibrator import OnlineCalibrator
    from sclam_ros.sim import simulate
    from sclam_ros.sim.effects import make_effect

    duration, first, last, effects = SCENARIOS[name]
    bag = Path(workdir) / f"{name.replace(' ', '_').replace('%', 'pc').replace('/', '')}_{seed}"
    truth = simulate(bag, duration=duration, seed=seed, effects=effects, overwrite=True)
    params = SclamParams.from_yaml(bag / "params.yaml")
    calibrator = OnlineCalibrator(params, config=config)
    rows = []  # (t since start, six values, detections so far)
    for estimate in iter_outputs(bag, params, calibrator):
        if estimate is not None:
            rows.append([estimate.stamp - truth["start_time"],
                         *(estimate.values[k] for k in CALIBRATION_KEYS), calibrator.radius_changes,
                         *(estimate.sigma[k] for k in RADII)])
    a = np.array(rows)
    t = a[:, 0]
    effect_set = [make_effect(n, v) for n, v in effects.items()]
    for effect in effect_set:
        effect.for_duration(duration)
    r_left, r_right = np.full(len(t), truth["wheel_radius_left"]), np.full(len(t), truth["wheel_radius_right"])
    for effect in effect_set:
        r_left, r_right = effect.radii(t, r_left, r_right)
    radius_error = 100 * np.abs(np.column_stack([a[:, 1] / r_left - 1, a[:, 2] / r_right - 1]))
    radius_z = np.abs(np.column_stack([a[:, 1] - r_left, a[:, 2] - r_right])) / a[:, 8:10]
    settled = t > SETTLE
    base_error = 100 * np.abs(a[settled, 3] / truth["wheel_base"] - 1)
    laser_mm = 1000 * np.hypot(a[settled, 4] - truth["laser_x"], a[settled, 5] - truth["laser_y"])
    laser_deg = np.degrees(np.abs(a[settled, 6] - truth["laser_yaw"]))
    detections = a[:, 7]
    out = {"scenario": name, "seed": seed,
           "base": base_error.max(), "laser_mm": laser_mm.max(), "laser_deg": laser_deg.max()}
    if first is None:
        out["false_alarms"] = detections[-1]
        out["hours_clean"] = (t[-1] - SETTLE) / 3600.0
        out["radius_settled"] = radius_error[settled].max()
        out["z_lag"], out["z_after"] = None, radius_z[settled]
        return out
    before = t < first
    out["false_alarms"] = detections[before][-1] if before.any() else 0.0
    out["hours_clean"] = max(0.0, first - SETTLE) / 3600.0
    after = np.flatnonzero((t >= first) & (detections > (detections[before][-1] if before.any() else 0)))
    out["delay"] = t[after[0]] - first if len(after) else math.nan
    out["from30"] = radius_error[t >= last + 30.0].max()
    out["from60"] = radius_error[t >= last + 60.0].max()
    out["z_lag"] = radius_z[(t >= first) & (t < first + 30.0)]
    out["z_after"] = radius_z[t >= last + 30.0]
    out["covered"] = covered_from(t, radius_z.max(axis=1), first)
    return out


def covered_from(t, z, start) -> float:
    """Seconds after `start` until z is first below 2 (nan: never)."""
    inside = np.flatnonzero((t >= start) & (z < 2.0))
    return t[inside[0]] - start if len(inside) else math.nan


def z_cell(samples) -> str:
    """RMS / worst of |err|/σ pooled over seeds (both radii), or '-'."""
    if not samples:
        return "-"
    z = np.concatenate([s.ravel() for s in samples])
    return f"{math.sqrt(np.mean(z ** 2)):.1f} / {z.max():.1f}"


def main():
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--jobs", type=int, default=2, help="processes (one per core)")
    ap.add_argument("--scenarios", nargs="+", default=list(SCENARIOS), choices=list(SCENARIOS))
    ap.add_argument("--set", nargs="+", default=[], metavar="SECTION.FIELD=VALUE",
                    help="tuning of the calibrator (sclam_ros/online/config.py)")
    args = ap.parse_args()
    config = configured(OnlineConfig(), args.set)
    workdir = scratch_dir("sclam_load_change_")
    jobs = [(name, seed, workdir, config) for name in args.scenarios for seed in range(1, args.seeds + 1)]
    with ProcessPoolExecutor(args.jobs) as pool:
        results = list(pool.map(run_one, jobs))
    rows = []
    for name in args.scenarios:
        mine = [r for r in results if r["scenario"] == name]
        worst = lambda key: max(r[key] for r in mine)  # noqa: E731
        alarms = sum(r["false_alarms"] for r in mine)
        hours = sum(r["hours_clean"] for r in mine)
        if "delay" in mine[0]:
            delays = [r["delay"] for r in mine]
            missed = sum(math.isnan(d) for d in delays)
            delay = f"{np.nanmedian(delays):.0f} / {np.nanmax(delays):.0f}" if missed < len(delays) else "never"
            delay += f" ({missed} missed)" if missed else ""
            radius = [f"{worst('from30'):.3f}", f"{worst('from60'):.3f}"]
            covered = [r["covered"] for r in mine]
            covered = (f"{np.nanmedian(covered):.0f} / {np.nanmax(covered):.0f}"
                       + (f" ({sum(map(math.isnan, covered))} never)" if any(map(math.isnan, covered)) else ""))
        else:
            delay = covered = "-"
            radius = [f"{worst('radius_settled'):.3f} (all)", "-"]
        rows.append([name, len(mine), delay, *radius, f"{worst('base'):.3f}",
                     f"{worst('laser_mm'):.2f}", f"{worst('laser_deg'):.3f}",
                     f"{alarms / hours:.1f}" if hours > 0 else "-",
                     z_cell([r["z_lag"] for r in mine if r["z_lag"] is not None]),
                     z_cell([r["z_after"] for r in mine]), covered])
    print(f"online calibrator (window_distance 100 m: radii memory fading over 100 m, change "
          f"points); worst over {args.seeds} seeds per scenario"
          + (f"; {' '.join(args.set)}" if args.set else ""))
    print(table(rows, ["scenario", "runs", "detection delay s (median / worst)",
                       "radius error from +30 s %", "from +60 s %", "wheel base error %",
                       "laser error mm", "laser yaw error deg", "false alarms / h",
                       "radius |err|/σ first 30 s after (RMS / worst)",
                       "from +30 s (RMS / worst)",
                       "first within 2σ s after (median / worst)"]))


if __name__ == "__main__":
    main()
