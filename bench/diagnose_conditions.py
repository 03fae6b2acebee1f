"""`sclam diagnose` on clean simulated recordings made under varied recording conditions:
how often it selects an effect that is not there, or reports structure the model lacks.

A clean recording has no effect at all; what varies is what real recordings vary and a
diagnosis must not mistake for an effect: the robot (wheel bases 0.35, 0.58 and 0.70 m),
the encoders (20 to 200 Hz, 1970 to 22 835 ticks per turn, with or without slip noise),
the laser (360°, 270°, 240° and 180° models at 5 to 25 Hz), the scene, how a missing return
is encoded (inf, NaN, 0, above range_max), when the scans fall between encoder samples
(scan phase) and how exactly they are stamped (stamp jitter). Scans are instantaneous
(time_increment 0), as in the recordings that raised issue 58.

Disjoint sets (docs/diagnose.md says which was used for what):
  tuning      one factor at a time against the default recording, seeds 1-4: what the
              diagnosis's structure test was checked on while it was changed;
  held_out_1  combinations of factors, seeds 101-120: reported once, then used to find
              and fix what it showed (the scans' stamp jitter, the whiteness test): tuning
              data from then on;
  held_out_2  other combinations, seeds 201-220: reported once, then three of its recordings
              used to find what it showed (motion regressors sharing the wheels' noise):
              tuning data from then on;
  held_out    combinations never used in any of these (other robots, encoders, lasers,
              scenes and stamping together), seeds 301-320: what is reported now.

Per condition: recordings, those with any effect selected (a false selection) and which,
those with unexplained structure and its most frequent (component, regressor).

Run: .venv/bin/python bench/diagnose_conditions.py [--split held_out] [--seeds 20]
     [--duration 120] [--jobs 2] [--conditions "NAME;NAME"]
"""
from __future__ import annotations

import argparse
import math
import sys
import time
from collections import Counter
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import scratch_dir, table  # noqa: E402

URG = {"fov": math.radians(240), "range_max": 5.6}
UST = {"fov": math.radians(270), "range_max": 30.0}
LMS = {"fov": math.radians(180)}

# name: simulate() keyword arguments; "conditions": RecordingConditions fields
TUNING = {
    "default": {},
    "scans on encoder samples": {"conditions": {"scan_phase": 0.0}},
    "200 Hz, 19 700 ticks": {"encoder_rate": 200.0, "conditions": {"ticks_per_revolution": 19700}},
    "50 Hz, 1970 ticks": {"conditions": {"ticks_per_revolution": 1970}},
    "270° laser": {"beams": 1081, "laser": UST},
    "exact encoders": {"slip_noise": 0.0},
    "stamp jitter 5 ms": {"conditions": {"scan_stamp_jitter": 0.005}},
    "no return as NaN": {"conditions": {"no_return": "nan"}},
    "pioneer": {"robot": "pioneer"},
}
HELD_OUT_1 = {
    "pioneer, 200 Hz fine, 270°, corridors, NaN, on samples": {
        "robot": "pioneer", "encoder_rate": 200.0, "beams": 1081, "laser": UST,
        "scene": "corridors",
        "conditions": {"ticks_per_revolution": 19700, "no_return": "nan", "scan_phase": 0.0}},
    "powerbot, exact encoders, 0 for no return, jitter 2 ms": {
        "slip_noise": 0.0, "conditions": {"no_return": "zero", "scan_stamp_jitter": 0.002,
                                          "scan_phase": 0.007}},
    "0.70 m base, 20 Hz coarse, URG 240° 5.6 m, above range_max": {
        "robot": "custom", "encoder_rate": 20.0, "beams": 683, "laser": URG,
        "conditions": {"ticks_per_revolution": 1970, "no_return": "above_max",
                       "scan_phase": 0.031}},
    "pioneer, 100 Hz, 180° at 25 Hz, exact encoders": {
        "robot": "pioneer", "encoder_rate": 100.0, "scan_rate": 25.0, "beams": 361,
        "laser": LMS, "slip_noise": 0.0, "conditions": {"scan_phase": 0.004}},
    "powerbot, 270° exact 200 Hz, corridors": {
        "encoder_rate": 200.0, "beams": 1081, "laser": UST, "scene": "corridors",
        "slip_noise": 0.0, "conditions": {"ticks_per_revolution": 19700, "scan_phase": 0.0}},
}
HELD_OUT_2 = {
    "pioneer, 50 Hz, 360°, office, NaN, jitter 1 ms": {
        "robot": "pioneer", "conditions": {"no_return": "nan", "scan_stamp_jitter": 0.001,
                                           "scan_phase": 0.011}},
    "powerbot, 100 Hz exact, URG 240° 5.6 m, inf, jitter 3 ms": {
        "encoder_rate": 100.0, "beams": 683, "laser": URG, "slip_noise": 0.0,
        "conditions": {"scan_stamp_jitter": 0.003, "scan_phase": 0.002}},
    "pioneer, 20 Hz coarse, 270°, corridors, above range_max": {
        "robot": "pioneer", "encoder_rate": 20.0, "beams": 1081, "laser": UST,
        "scene": "corridors", "conditions": {"no_return": "above_max", "scan_phase": 0.019}},
    "0.70 m base, 200 Hz fine, 180° at 25 Hz, 0 for no return, on samples": {
        "robot": "custom", "encoder_rate": 200.0, "scan_rate": 25.0, "beams": 361,
        "laser": LMS, "conditions": {"ticks_per_revolution": 19700, "no_return": "zero",
                                     "scan_phase": 0.0}},
    "powerbot, 50 Hz 1970 ticks, 360° at 15 Hz, corridors, jitter 2 ms": {
        "scan_rate": 15.0, "scene": "corridors",
        "conditions": {"ticks_per_revolution": 1970, "scan_stamp_jitter": 0.002,
                       "scan_phase": 0.005}},
}
HELD_OUT = {
    "powerbot, 200 Hz, 270° at 10 Hz, office, NaN, jitter 2 ms": {
        "encoder_rate": 200.0, "beams": 1081, "laser": UST,
        "conditions": {"no_return": "nan", "scan_stamp_jitter": 0.002, "scan_phase": 0.013}},
    "pioneer, 50 Hz exact, 180° at 5 Hz, corridors": {
        "robot": "pioneer", "slip_noise": 0.0, "scan_rate": 5.0, "beams": 181, "laser": LMS,
        "scene": "corridors", "conditions": {"scan_phase": 0.009}},
    "0.70 m base, 100 Hz 1970 ticks, 360°, corridors, 0 for no return, jitter 1 ms": {
        "robot": "custom", "encoder_rate": 100.0, "scene": "corridors",
        "conditions": {"ticks_per_revolution": 1970, "no_return": "zero",
                       "scan_stamp_jitter": 0.001, "scan_phase": 0.003}},
    "powerbot, 20 Hz, URG 240° 5.6 m, office, above range_max, on samples": {
        "encoder_rate": 20.0, "beams": 683, "laser": URG,
        "conditions": {"no_return": "above_max", "scan_phase": 0.0}},
    "pioneer, 100 Hz 19 700 ticks, 270° at 25 Hz, corridors, jitter 3 ms": {
        "robot": "pioneer", "encoder_rate": 100.0, "scan_rate": 25.0, "beams": 1081, "laser": UST,
        "scene": "corridors", "conditions": {"ticks_per_revolution": 19700,
                                             "scan_stamp_jitter": 0.003, "scan_phase": 0.017}},
}
SPLITS = {"tuning": (TUNING, 1), "held_out_1": (HELD_OUT_1, 101), "held_out_2": (HELD_OUT_2, 201),
          "held_out": (HELD_OUT, 301)}


def simulate_options(condition, drop=()):
    """simulate()'s keyword arguments for a condition (one of the dicts above), its
    "conditions" made a RecordingConditions; ``drop``: keys left to simulate's default."""
    from sclam_ros.sim.conditions import RecordingConditions

    kwargs = {k: v for k, v in condition.items() if k not in drop}
    kwargs["conditions"] = RecordingConditions(**kwargs.get("conditions", {}))
    return kwargs


def run_case(conditions_by_name, name, seed, duration, workdir):
    from sclam_ros.core.params import SclamParams
    from sclam_ros.diagnosis.diagnose import diagnose_keyframes
    from sclam_ros.io.recording import read_recording
    from sclam_ros.sim import simulate

    bag = Path(workdir) / f"{list(conditions_by_name).index(name)}_{seed}"
    start = time.perf_counter()
    simulate(bag, duration=duration, seed=seed, overwrite=True,
             **simulate_options(conditions_by_name[name]))
    params = SclamParams.from_yaml(bag / "params.yaml")
    keyframes = read_recording(bag, params, keep_scan_points=True).keyframes
    report = diagnose_keyframes(keyframes, params).report
    return {"condition": name, "seed": seed,
            "selected": [e["name"] for e in report["effects"] if e["selected"]],
            "unexplained": [(u["component"], u["regressor"]) for u in report["unexplained"]],
            "seconds": time.perf_counter() - start}


def _row(name, results):
    selected = [r for r in results if r["selected"]]
    structured = [r for r in results if r["unexplained"]]
    which = Counter(e for r in selected for e in r["selected"])
    top = Counter(u for r in structured for u in r["unexplained"]).most_common(1)
    return [name, len(results), len(selected),
            ", ".join(f"{e} {n}" for e, n in which.most_common()) or "–",
            len(structured), f"{top[0][0][0]} ~ {top[0][0][1]} ({top[0][1]})" if top else "–"]


def main():
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--split", choices=sorted(SPLITS), default="held_out")
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--duration", type=float, default=120.0)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--conditions", default="", help="names separated by ';' (default: all)")
    args = ap.parse_args()
    by_name, first_seed = SPLITS[args.split]
    names = [n.strip() for n in args.conditions.split(";") if n.strip()] or list(by_name)
    unknown = [n for n in names if n not in by_name]
    if unknown:
        ap.error(f"unknown condition(s) {unknown}; {args.split} has {list(by_name)}")
    work = scratch_dir("sclam_diagnose_conditions_")
    seeds = range(first_seed, first_seed + args.seeds)
    results = {n: [] for n in names}
    with ProcessPoolExecutor(args.jobs) as pool:
        futures = [(n, s, pool.submit(run_case, by_name, n, s, args.duration, work))
                   for n in names for s in seeds]
        for n, s, future in futures:
            r = future.result()
            results[n].append(r)
            print(f"{n} seed {s}: selected {r['selected'] or 'none'}, unexplained "
                  f"{r['unexplained'] or 'none'}, {r['seconds']:.0f} s", flush=True)
    print(f"\n{args.split}: clean recordings, seeds {first_seed}-{first_seed + args.seeds - 1}, "
          f"{args.duration:.0f} s each")
    print(table([_row(n, results[n]) for n in names],
                ["condition", "recordings", "with an effect selected", "which",
                 "with unexplained structure", "most frequent"]))


if __name__ == "__main__":
    main()
