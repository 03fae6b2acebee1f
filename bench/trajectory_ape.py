"""How far the robot's own odometry is from the truth with the nominal and with the calibrated
parameters: absolute pose error (APE) of the trajectories `sclam calibrate --trajectory` writes,
computed with evo's API, over simulated recordings.

Per seed: simulate a recording, run `sclam calibrate BAG --params BAG/params.yaml
--trajectory run.tum`, and compare OUT.nominal.tum, OUT.calibrated.tum and OUT.tum (the
optimised path) with OUT.truth.tum. evo's APE on the translation part, RMSE over all poses:
  - "as written": no alignment. All four files start at the first scan's pose (the frame
    `--trajectory` writes them in), so this is the drift the robot accumulates from its start,
    what `evo_ape tum run.truth.tum run.calibrated.tum` prints;
  - "aligned": after evo's SE(3) Umeyama alignment of each to the truth (`evo_ape ... --align`),
    which removes a common rotation and offset and so hides part of the drift.

Run: .venv/bin/python bench/trajectory_ape.py [--seeds 5] [--duration 120] [--robot powerbot]
"""
import argparse
import contextlib
import copy
import io
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from common import table
from evo.core import metrics, sync
from evo.tools import file_interface

from sclam_ros.cli.main import main as sclam
from sclam_ros.io.export import trajectory_paths
from sclam_ros.sim import simulate


def ape_rmse(truth_file, estimate_file, align):
    """evo's APE (translation part, m) RMSE of one TUM trajectory against the truth."""
    reference = file_interface.read_tum_trajectory_file(str(truth_file))
    estimate = file_interface.read_tum_trajectory_file(str(estimate_file))
    reference, estimate = sync.associate_trajectories(reference, estimate, max_diff=1e-3)
    if align:
        estimate = copy.deepcopy(estimate)
        estimate.align(reference, correct_scale=False)
    ape = metrics.APE(metrics.PoseRelation.translation_part)
    ape.process_data((reference, estimate))
    return ape.get_statistic(metrics.StatisticsType.rmse)


def run_seed(workdir, robot, duration, seed):
    """{(trajectory, aligned): APE RMSE (m)} and the seconds `sclam calibrate` took."""
    bag = Path(workdir) / f"{robot}_{seed}"
    simulate(bag, robot=robot, duration=duration, seed=seed, overwrite=True)
    out = Path(workdir) / f"{robot}_{seed}.tum"
    start = time.perf_counter()
    # Its table and its info lines are not this bench's; its warnings and errors are.
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()) as err:
        rc = sclam(["calibrate", str(bag), "--params", str(bag / "params.yaml"), "--quiet",
                    "--trajectory", str(out)])
    seconds = time.perf_counter() - start
    for line in err.getvalue().splitlines():
        if not line.startswith("sclam calibrate: info:"):
            print(f"seed {seed}: {line}", file=sys.stderr)
    if rc != 0:
        raise SystemExit(f"sclam calibrate failed on seed {seed} (exit {rc})")
    paths = trajectory_paths(out)
    return {(name, align): ape_rmse(paths["truth"], paths[name], align)
            for name in ("nominal", "calibrated", "optimised") for align in (False, True)}, seconds


def main():
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--duration", type=float, default=120.0, help="s of driving per recording")
    ap.add_argument("--robot", default="powerbot")
    args = ap.parse_args()
    rows, ratios = [], []
    with tempfile.TemporaryDirectory(prefix="sclam_ape_") as workdir:
        for seed in range(1, args.seeds + 1):
            ape, seconds = run_seed(workdir, args.robot, args.duration, seed)
            ratio = ape["calibrated", False] / ape["nominal", False]
            ratios.append(ratio)
            rows.append([seed, f"{args.duration:.0f}",
                         f"{ape['nominal', False]:.3f}", f"{ape['calibrated', False]:.3f}",
                         f"{ratio:.3f}", f"{ape['nominal', True]:.3f}",
                         f"{ape['calibrated', True]:.3f}", f"{ape['optimised', False]:.3f}",
                         f"{seconds:.0f}"])
            print(f"seed {seed}: nominal {ape['nominal', False]:.3f} m, calibrated "
                  f"{ape['calibrated', False]:.3f} m", flush=True)
    print(f"\n{args.robot}, {args.seeds} simulated recordings (office scene): APE RMSE of the "
          "translation (m) against the ground truth; odometry = wheel odometry integrated with "
          "the nominal / the calibrated parameters; ratio = calibrated / nominal, as written")
    print(table(rows, ["seed", "duration (s)", "APE nominal", "APE calibrated", "ratio",
                       "nominal aligned", "calibrated aligned", "APE optimised",
                       "calibrate (s)"]))
    print(f"ratio: median {np.median(ratios):.3f}, max {np.max(ratios):.3f}")


if __name__ == "__main__":
    main()
