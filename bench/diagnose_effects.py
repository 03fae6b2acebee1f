"""`sclam diagnose` on simulated recordings with known effects, several seeds each
(docs/diagnose.md).

Scenarios (PowerBot, office world, --duration s unless said):

  carpet        one room's carpet: extra slip noise of 0.6 % of a revolution (independent
                of the 0.5 % everywhere: variance ratio 2.44) inside room n1 (world
                x 0-11 m, y 9-16 m). Correct: floor_noise selected (and nothing else);
                where the route never enters the room, nothing selected (it is clean).
                Region overlap: time inside the found rectangle ∩ inside the room over
                their union, on the true trajectory; size error: variance ratio vs 2.44,
                also in units of the reported σ of the ratio; time in the room per seed.
  speed_radius  each wheel's radius grows with its own speed, r·(1 + 0.1·u²) (not in
                the library). Correct: no library effect selected, and the regressor
                named first for what is unexplained is the speed (v, |v| or v·|v|).
  clean         no effect. Correct: nothing selected.
  time_offset, lateral_slip, scan_motion: the library's mean effects (20 ms, 0.05 s, a
                10 Hz laser sweeping its whole period), 90 s. Correct: exactly that
                effect (scan_distortion for scan_motion) selected.

--held-out: seed s is recorded under held-out condition number s mod 5 of
bench/diagnose_conditions.py's HELD_OUT (robot, encoders, laser, scene, no-return encoding,
scan phase, stamp jitter), so 10 seeds cover each twice; use seeds from 301 (--first-seed
301), disjoint from the tuning seeds. Carpet keeps the office scene and the default slip
noise (a condition's "scene" and "slip_noise" are dropped): its room n1 is the office's,
and the simulated carpet scales the recording's slip noise (sim.effects.FloorNoiseArea),
so on exact encoders (slip_noise 0) there would be no carpet at all.

Size error: carpet's variance ratio against 2.44; time_offset's value against the 20 ms
simulated (the time_offset entry of the report, selected or not). "Within 20 %": seeds
selected correctly with a size error within ±20 %.

A false selection is a selected effect other than the correct one. "Else named": seeds
not selected correctly where the report names the correct effect as fitting the data about
as well as a simpler one it selected (the one-standard-error rule's alternatives). Top regressor: the
most frequent first entry of `unexplained_cause` over the seeds (with how many seeds).

Run: .venv/bin/python bench/diagnose_effects.py [--seeds 5] [--duration 180]
     [--scenarios carpet,speed_radius,clean,...] [--jobs 1] [--without-walls]
     [--set SECTION.FIELD=VALUE ...]   (a DiagnoseConfig value, e.g. selection.noise_folds=10)
     [--held-out --first-seed 301]
"""
from __future__ import annotations

import argparse
import sys
import time
from collections import Counter
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import configured, scratch_dir, table  # noqa: E402
from diagnose_conditions import HELD_OUT, simulate_options  # noqa: E402

from sclam_ros.diagnosis.config import DiagnoseConfig  # noqa: E402

ROOM = {"x_min": 0.0, "x_max": 11.0, "y_min": 9.0, "y_max": 16.0}  # room n1 of the office
EXTRA_SLIP = 0.006  # fraction of a revolution after one revolution
SPEED_REGRESSORS = ("v", "abs_v", "v_squared")
# name: (simulator effects, the library effect that should be selected, duration or None)
SCENARIOS = {
    "carpet": ({"floor_noise_area": {"extra": EXTRA_SLIP, **ROOM}}, "floor_noise", None),
    "speed_radius": ({"speed_dependent_radius": 0.1}, None, None),
    "clean": (None, None, None),
    "time_offset": ({"time_offset": 0.02}, "time_offset", 90.0),
    "lateral_slip": ({"lateral_slip": 0.05}, "lateral_slip", 90.0),
    "scan_motion": ({"scan_motion": 1.0}, "scan_distortion", 90.0),
}


def _world_positions(bag, truth):
    """Ground-truth (stamps, odom-frame xy, world xy) of the recording."""
    from sclam_ros.io.recording import read_ground_truth

    stamps, poses = read_ground_truth(bag)
    o = np.array(truth["odom_origin_in_world"])
    c, s = np.cos(o[2]), np.sin(o[2])
    world = np.column_stack([o[0] + c * poses[:, 0] - s * poses[:, 1],
                             o[1] + s * poses[:, 0] + c * poses[:, 1]])
    return stamps, poses[:, :2], world


def _in_region(xy, region):
    """Points inside the found rectangle (its sides along the map's axes)."""
    a = np.radians(region["angle_deg"])
    u = np.cos(a) * xy[:, 0] + np.sin(a) * xy[:, 1]
    v = -np.sin(a) * xy[:, 0] + np.cos(a) * xy[:, 1]
    return ((u >= region["along"][0]) & (u <= region["along"][1])
            & (v >= region["across"][0]) & (v <= region["across"][1]))


def _size(effect, true_value):
    """The reported value's error against the simulated one: relative, and in its σ."""
    if effect["value"] is None:
        return {}
    out = {"size_error": float(effect["value"] / true_value - 1.0)}
    if effect["sigma"]:
        out["size_z"] = float((effect["value"] - true_value) / effect["sigma"])
    return out


def held_out_condition(seed):
    """The name of the held-out recording condition seed ``seed`` runs under."""
    return list(HELD_OUT)[seed % len(HELD_OUT)]


def run_case(scenario, seed, duration, workdir, walls=True, config=None, held_out=False):
    from sclam_ros.core.params import SclamParams
    from sclam_ros.diagnosis.diagnose import diagnose_keyframes
    from sclam_ros.io.recording import read_recording
    from sclam_ros.sim import simulate
    from sclam_ros.sim.effects import make_effect

    effects, expected, fixed = SCENARIOS[scenario]
    duration = fixed or duration
    bag = Path(workdir) / f"{scenario}_{seed}"
    condition = held_out_condition(seed) if held_out else None
    options = simulate_options(HELD_OUT[condition], drop=("scene", "slip_noise")
                               if scenario == "carpet"
                               else ()) if condition else {}
    truth = simulate(bag, duration=duration, seed=seed, effects=effects, overwrite=True,
                     **options)
    params = SclamParams.from_yaml(bag / "params.yaml")
    start = time.perf_counter()
    keyframes = read_recording(bag, params, keep_scan_points=walls).keyframes
    read_s = time.perf_counter() - start
    report = diagnose_keyframes(keyframes, params, config=config or DiagnoseConfig()).report
    out = {"scenario": scenario, "seed": seed, "duration": duration, "condition": condition,
           "seconds": time.perf_counter() - start, "read_seconds": read_s,
           "selected": [e["name"] for e in report["effects"] if e["selected"]],
           # value ± σ of each selected effect, in its units
           "values": {e["name"]: (e["value"], e["sigma"]) for e in report["effects"]
                      if e["selected"]},
           "cause": (report["unexplained_cause"] or [{}])[0].get("regressor"),
           "cause_fraction": (report["unexplained_cause"] or [{}])[0].get("fraction_explained"),
           "not_separable": report["not_separable"], "warnings": report["warnings"],
           # effects the report names as fitting about as well as a selected one
           "alternatives": sorted({a for e in report["effects"] if e["selected"]
                                   for a in e["evidence"].get("alternatives", [])})}
    if scenario == "carpet":
        stamps, odom_xy, world_xy = _world_positions(bag, truth)
        true_in = ((world_xy[:, 0] >= ROOM["x_min"]) & (world_xy[:, 0] <= ROOM["x_max"])
                   & (world_xy[:, 1] >= ROOM["y_min"]) & (world_xy[:, 1] <= ROOM["y_max"]))
        out["room_visited"] = bool(true_in.any())
        out["room_seconds"] = float(np.sum(np.diff(stamps)[true_in[:-1]]))
        if not out["room_visited"]:  # the route never reaches the carpet: a clean recording
            expected = None
    out["correct"] = out["selected"] == ([expected] if expected else [])
    if scenario == "speed_radius":
        out["correct"] = out["correct"] and out["cause"] in SPEED_REGRESSORS
    floor = next(e for e in report["effects"] if e["name"] == "floor_noise")
    # The best rectangle's evidence against its penalties, on every run (clean ones too).
    evidence = floor["evidence"]
    if evidence.get("likelihood_ratio") is not None:
        out["floor_evidence"] = (evidence["likelihood_ratio"], evidence["bic_penalty"],
                                 evidence.get("heldout_likelihood_ratio"),
                                 evidence.get("heldout_penalty"))
    if scenario == "carpet" and out["room_visited"] and "region" in floor:
        found_in = _in_region(odom_xy, floor["region"])
        out["overlap"] = float(np.sum(true_in & found_in) / max(np.sum(true_in | found_in), 1))
        out.update(_size(floor, make_effect("floor_noise_area",
                                            effects["floor_noise_area"]).variance_ratio()))
        out["floor_selected"] = floor["selected"]
        out["wall_support"] = floor["region"].get("wall_support")
    if scenario == "time_offset":
        out.update(_size(next(e for e in report["effects"] if e["name"] == "time_offset"),
                         effects["time_offset"]))
    return out


def _row(scenario, results):
    def expected(r):  # a carpet route that never reaches the room is a clean recording
        return SCENARIOS[scenario][1] if r.get("room_visited", True) else None

    false = sum(len([n for n in r["selected"] if n != expected(r)]) for r in results)
    causes = Counter(r["cause"] for r in results if r["cause"])
    top = causes.most_common(1)
    overlaps = [r["overlap"] for r in results if "overlap" in r]
    sizes = [r["size_error"] for r in results if "size_error" in r]
    size_z = [r["size_z"] for r in results if "size_z" in r]
    named = sum(1 for r in results if not r["correct"] and expected(r) in r["alternatives"])
    return [scenario, len(results), f"{sum(r['correct'] for r in results)}/{len(results)}", named,
            (f"{min(overlaps):.2f}–{max(overlaps):.2f}" if overlaps else "–"),
            (f"{min(sizes):+.0%}…{max(sizes):+.0%}" if sizes else "–"),
            (f"{min(size_z):+.1f}…{max(size_z):+.1f}" if size_z else "–"),
            (f"{sum(r['correct'] and abs(r.get('size_error', 1)) <= 0.2 for r in results)}"
             f"/{len(results)}" if sizes else "–"), false,
            (f"{top[0][0]} ({top[0][1]}/{len(results)})" if top else "–"),
            f"{np.median([r['seconds'] for r in results]):.0f}"]


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--first-seed", type=int, default=1)
    ap.add_argument("--duration", type=float, default=180.0)
    ap.add_argument("--scenarios", default=",".join(SCENARIOS))
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--without-walls", action="store_true",
                    help="read the recordings without their scans' points: no map of walls "
                         "bounds the floor region (what the likelihood alone finds)")
    ap.add_argument("--set", action="append", default=[], metavar="SECTION.FIELD=VALUE",
                    help="a DiagnoseConfig value other than the default (repeatable)")
    ap.add_argument("--held-out", action="store_true",
                    help="seed s under bench/diagnose_conditions.py's held-out condition "
                         "number s mod 5 (use --first-seed 301)")
    args = ap.parse_args()
    config = configured(DiagnoseConfig(), args.set)
    names = [n.strip() for n in args.scenarios.split(",")]
    work = scratch_dir("sclam_diagnose_bench_")
    cases = [(n, s) for n in names for s in range(args.first_seed, args.first_seed + args.seeds)]
    results = {n: [] for n in names}
    with ProcessPoolExecutor(args.jobs) as pool:
        futures = [pool.submit(run_case, n, s, args.duration, work, not args.without_walls, config,
                               args.held_out)
                   for n, s in cases]
        for (n, s), f in zip(cases, futures):
            r = f.result()
            results[n].append(r)
            extra = "".join(f" {k} {r[k]:.2f}" for k in ("overlap", "size_error", "size_z",
                                                          "wall_support") if r.get(k) is not None)
            extra += f", {r['room_seconds']:.0f} s in the room" if r.get("room_seconds") else ""
            extra += "" if r.get("room_visited", True) else " (the route never enters the room)"
            extra += f", named as fitting as well: {r['alternatives']}" if r["alternatives"] else ""
            if r.get("floor_evidence") and n in ("carpet", "clean"):
                lr, bic, held, held_penalty = r["floor_evidence"]
                extra += (f", floor_noise likelihood ratio {lr:.1f} (penalty {bic:.1f}), held out "
                          f"{held if held is None else round(held, 1)} (penalty "
                          f"{held_penalty if held_penalty is None else round(held_penalty, 1)})")
            values = ", ".join(f"{name} {v:.4g}" + (f" ± {sd:.2g}" if sd else "")
                               for name, (v, sd) in r["values"].items())
            where = f" ({r['condition']})" if r["condition"] else ""
            print(f"{n} seed {s}{where}: selected {r['selected'] or 'none'}"
                  f"{f' ({values})' if values else ''}, cause {r['cause']} "
                  f"({r['cause_fraction'] or 0:.2f}){extra}, not separable "
                  f"{[p['effects'] for p in r['not_separable']]}, {r['seconds']:.0f} s", flush=True)
    print(f"\n{args.seeds} seeds from {args.first_seed}, {args.duration:.0f} s "
          "(90 s for the library's mean effects)"
          + (", held-out conditions (seed mod 5; carpet in the office)" if args.held_out else "")
          + (", without the map of walls" if args.without_walls else "")
          + (f", {', '.join(args.set)}" if args.set else ""))
    print(table([_row(n, results[n]) for n in names],
                ["scenario", "seeds", "selected correctly", "else named as fitting as well",
                 "region overlap", "size error", "size error / σ", "within 20 %",
                 "false selections", "top regressor", "s per run"]))


if __name__ == "__main__":
    main()
