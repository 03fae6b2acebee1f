"""sclam diagnose on one simulated recording per library effect (seed 1), the cases of
test/test_diagnose*.py: what is selected, its estimate against what was injected, and the
held-out error (NLL per edge, lower is better) of the base and the extended model.
Effects outside the library are listed with the first regressor named unexplained.

Run: .venv/bin/python bench/diagnose_examples.py [--jobs 2] [--set SECTION.FIELD=VALUE ...]
     (--set: a DiagnoseConfig value other than the default, e.g. floor.within=2)
"""
from __future__ import annotations

import argparse
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import configured, scratch_dir, table  # noqa: E402

from sclam_ros.diagnosis.config import DiagnoseConfig  # noqa: E402

# label, simulate() keywords, duration s, effect whose value is compared, what was injected
CASES = [
    ("`time_offset` 0.02 s", {"effects": {"time_offset": 0.02}}, 90.0, "time_offset", "0.02 s"),
    ("`lateral_slip` 0.05 s", {"effects": {"lateral_slip": 0.05}}, 90.0, "lateral_slip", "0.05 s"),
    ("`radius_drift` −30 / −10 %/h", {"effects": {"radius_drift": {"left": -0.30, "right": -0.10}}},
     300.0, "radius_drift", "−30 / −10 %/h"),
    ("`floor_noise_region`, slip σ ×2 beyond the route's median x (variance ratio 4)",
     "floor", 180.0, "floor_noise", "ratio 4"),
    ("`scan_motion` (10 Hz laser sweeping its whole period)", {"effects": {"scan_motion": 1.0}},
     90.0, "scan_distortion", "delay T/2 = 0.05 s"),
    ("none", {}, 90.0, None, "–"),
    ("`wheel_eccentricity` 3 % (not in the library)", {"effects": {"wheel_eccentricity": 0.03}},
     40.0, None, "–"),
    ("`speed_dependent_slip` 0.15 (not in the library)", {"effects": {"speed_dependent_slip": 0.15}},
     60.0, None, "–"),
]


def run_case(job):
    number, label, options, duration, name, injected, workdir, config = job
    from sclam_ros.core.params import SclamParams
    from sclam_ros.diagnosis.diagnose import diagnose_keyframes
    from sclam_ros.io.recording import read_ground_truth, read_recording
    from sclam_ros.sim import simulate

    bag = Path(workdir) / f"case{number}"
    if options == "floor":  # the noisy half: beyond the median x of the route's time
        route = Path(workdir) / f"route{number}"
        truth = simulate(route, duration=duration, seed=1, overwrite=True)
        _, poses = read_ground_truth(route)
        x_min = float(np.median(poses[:, 0]) + truth["odom_origin_in_world"][0])
        options = {"effects": {"floor_noise_region": {"factor": 2.0, "x_min": x_min}}}
    simulate(bag, duration=duration, seed=1, overwrite=True, **options)
    params = SclamParams.from_yaml(bag / "params.yaml")
    keyframes = read_recording(bag, params, keep_scan_points=True).keyframes
    report = diagnose_keyframes(keyframes, params, config=config).report
    selected = [e["name"] for e in report["effects"] if e["selected"]]
    estimate = "–"
    if name is not None:
        effect = next(e for e in report["effects"] if e["name"] == name)
        value = effect.get("value")
        drifts = effect["evidence"].get("params")
        if name == "radius_drift" and drifts is not None:  # both wheels' drifts
            estimate = " / ".join(f"{100 * a:+.1f}" for a in drifts) + " %/h"
        elif value is not None:
            estimate = f"{value:.4g} ± {effect['sigma']:.2g}" if effect.get("sigma") else f"{value:.4g}"
    unexplained = [u["regressor"] for u in report["unexplained"]
                   if u["component"].startswith("odometry") and u["regressor"] != "lag"]
    return [label, f"{duration:.0f} s", ", ".join(selected) or "none", injected, estimate,
            f"{report['base']['error']:.3f} → {report['extended']['error']:.3f}",
            unexplained[0] if unexplained else "–"]


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--set", action="append", default=[], metavar="SECTION.FIELD=VALUE",
                    help="a DiagnoseConfig value other than the default (repeatable)")
    args = ap.parse_args()
    config = configured(DiagnoseConfig(), args.set)
    workdir = scratch_dir("sclam_diag_examples_")
    jobs = [(number, *case, workdir, config) for number, case in enumerate(CASES)]
    with ProcessPoolExecutor(args.jobs) as pool:
        rows = list(pool.map(run_case, jobs))
    print(f"seed 1; held-out error: NLL per edge of the {config.selection.folds}-fold time blocks, "
          "base → extended" + (f"; {', '.join(args.set)}" if args.set else ""))
    print(table(rows, ["injected (simulator)", "run", "selected", "injected value", "estimate",
                       "held-out error base → extended", "first odometry regressor unexplained"]))


if __name__ == "__main__":
    main()
