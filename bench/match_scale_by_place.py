"""Where on a drive the scan matches come out long: their scale along a corridor and elsewhere.

A calibration's wheel radii follow the scale of the scan matches as the graph weighs them.
Here the matches of simulated drives (a row of bench/sensor_matrix.py, default the low-cost
laser; --seeds seeds, --duration s each, matched as `sclam calibrate` does) are split by
where they were made:

  - along a corridor: the laser inside a corridor's band (sim/world.py CORRIDORS: the
    office's one corridor, world y 6.5-9 m and x 0-22 m, or the four of the corridors
    scene) and moving within 20° of that corridor's direction;
  - elsewhere: every other match (in the corridors scene: in its lobbies, and turning or
    crossing inside its corridors).

The same matches are also split by how well each one fixes its own motion: σ/L, the σ of
the matched translation along the true motion (from the information the graph gives the
match, translation marginal) over the motion's length L. A match whose scans do not fix
its motion (in the middle of a bare corridor, its walls out of range) reports where it
settled, and its σ says how little that means.

Per group: the number of matches, its share of the matches' weight (information along the
motion), and the scale of the matched translations, weighted as the graph weighs them,
1 + Σ w·e·L / Σ w·L² (e the error along the true motion, L its length, w the information
along it), and unweighted, Σ z·z_true / Σ |z_true|² (bench/sensor_matrix.py's), each ±
its standard error from resampling the seeds. Matches shorter than 2 cm are left out (their
direction is not defined).

With --starts, per group also the unweighted scale of KISS-ICP's answers (where each
refinement started) and of the refinement started at the true motion instead, over the
matches the front end's recorded refinements give (common.observed_refinements): whether a
group's matches are short because of where they start or because of what their scans say.

Run: .venv/bin/python bench/match_scale_by_place.py [--row 4] [--seeds 80] [--duration 120] [--jobs 2] [--starts]
     (--row: any row of bench/sensor_matrix.py; the split by place needs a scene with
      corridors, the office's or the corridors scene's)
"""
from __future__ import annotations

import argparse
import contextlib
import shutil
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import observed_refinements, scratch_dir, table  # noqa: E402
from sensor_matrix import ROWS, along_motion, matches_against_truth  # noqa: E402

from sclam_ros.sim.world import CORRIDORS  # noqa: E402

ALONG = np.radians(20.0)  # motion within this of the corridor's direction
# Groups by σ/L of the match along its motion: (label, lower bound, upper bound).
FIXED = (("motion fixed to σ/L < 3 %", 0.0, 0.03), ("σ/L 3–10 %", 0.03, 0.10),
         ("σ/L 10–30 %", 0.10, 0.30), ("σ/L 30 % or more", 0.30, np.inf))


def run_seed(job):
    """Per group: (Σ w·e·L, Σ w·L², Σ e·L, Σ L², matches, and with --starts Σ e·L of
    KISS-ICP's answers and of the refinement from the true motion, Σ L² of those matches)
    of one simulated drive."""
    row, seed, duration, workdir, starts = job
    from sclam_ros.core import se2
    from sclam_ros.core.params import SclamParams
    from sclam_ros.io.recording import read_recording
    from sclam_ros.sim import simulate

    bag = Path(workdir) / f"seed{seed}"
    truth = simulate(bag, duration=duration, seed=seed, overwrite=True, **row)
    params = SclamParams.from_yaml(bag / "params.yaml")
    # Recording every refinement keeps each reference scan: only when --starts asks.
    with observed_refinements() if starts else contextlib.nullcontext([]) as calls:
        keyframes = read_recording(bag, params).keyframes
    z, z_true, information, start = matches_against_truth(bag, truth, keyframes)
    shutil.rmtree(bag)  # 80 recordings would fill the scratch directory
    start = se2.compose(np.broadcast_to(np.array(truth["odom_origin_in_world"], float), start.shape), start)
    keep, error, length, weight = along_motion(z, z_true, information)
    heading = start[keep, 2] + np.arctan2(z_true[keep, 1], z_true[keep, 0])  # of the motion, world
    bands = CORRIDORS.get(row.get("scene", "office"), ())
    corridor = along_a_corridor(bands, start[keep, :2], heading)
    unit = z_true[keep, :2] / length[:, None]
    covariance = np.linalg.inv(information[keep])[:, :2, :2]
    sigma_share = np.sqrt(np.einsum("mi,mij,mj->m", unit, covariance, unit)) / length
    groups = [("along a corridor", corridor), ("elsewhere", ~corridor)] if bands else []
    groups += [(label, (sigma_share >= low) & (sigma_share < high)) for label, low, high in FIXED]
    groups.append(("all", np.ones_like(corridor)))
    start_errors = (_start_errors(calls, z[keep], z_true[keep], unit) if starts
                    else np.full((len(unit), 2), np.nan))
    found = np.isfinite(start_errors).all(axis=1)
    return {group: (np.sum(weight[k] * error[k] * length[k]), np.sum(weight[k] * length[k] ** 2),
                    np.sum(error[k] * length[k]), np.sum(length[k] ** 2), int(k.sum()),
                    *np.sum(start_errors[k & found] * length[k & found, None], axis=0),
                    np.sum(length[k & found] ** 2))
            for group, k in groups}


def _start_errors(calls, z, z_true, unit):
    """(M, 2): the error along the true motion (`unit`) of KISS-ICP's answer and of the
    refinement started at the true motion, for each match (refined z `z`), from the
    refinements `calls` recorded (common.observed_refinements); NaN where not found."""
    from sclam_ros.frontend import point_to_line

    by_z = {tuple(np.round(out[0], 12)): (reference, points, z_icp)
            for reference, points, z_icp, out in calls if out[0] is not None}
    errors = np.full((len(z), 2), np.nan)
    for m in range(len(z)):
        call = by_z.get(tuple(np.round(z[m], 12)))
        if call is None:
            continue
        reference, points, z_icp = call
        from_truth, used, _ = point_to_line.refine_with_covariance(reference, points, z_true[m])
        if used:
            errors[m] = [(z_icp[:2] - z_true[m, :2]) @ unit[m],
                         (from_truth[:2] - z_true[m, :2]) @ unit[m]]
    return errors


def along_a_corridor(bands, position, heading):
    """(M,) bool: each match made inside one of the corridor `bands` (sim/world.py
    CORRIDORS) and moving within ALONG of that corridor's direction (world `heading`)."""
    x, y = position[:, 0], position[:, 1]
    along = np.zeros(len(x), bool)
    for (x0, x1), (y0, y1), axis in bands:
        off_axis = np.abs(np.sin(heading) if axis == 0 else np.cos(heading))
        along |= (x > x0) & (x < x1) & (y > y0) & (y < y1) & (off_axis < np.sin(ALONG))
    return along


def _ratio_with_error(numerator, denominator, rng):
    """Σ numerator / Σ denominator over seeds, and its standard error from resampling them."""
    pick = rng.integers(0, len(numerator), (1000, len(numerator)))
    return (numerator.sum() / denominator.sum(),
            float(np.std(numerator[pick].sum(1) / denominator[pick].sum(1))))


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--row", type=int, default=4, help="row of bench/sensor_matrix.py (default: low-cost)")
    ap.add_argument("--seeds", type=int, default=80)
    ap.add_argument("--duration", type=float, default=120.0)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--starts", action="store_true",
                    help="also the unweighted scale of KISS-ICP's answers and of the refinement "
                         "started at the true motion")
    args = ap.parse_args()
    name, row = list(ROWS.items())[args.row]
    workdir = scratch_dir("match_scale_by_place")
    with ProcessPoolExecutor(args.jobs) as pool:
        results = list(pool.map(run_seed, [(row, seed, args.duration, workdir, args.starts)
                                           for seed in range(1, args.seeds + 1)]))
    rng = np.random.default_rng(0)
    starts_rng = np.random.default_rng(1)  # its own draws: the other columns stay as without
    total_weight = sum(r["all"][1] for r in results)
    cells = []
    for place in results[0]:
        sums = np.array([r[place] for r in results], float)  # (seeds, 8)
        if not sums[:, 4].any():
            cells.append([place, 0, "0.00", "—", "—"] + ["—", "—"] * args.starts)
            continue
        weighted, weighted_error = _ratio_with_error(sums[:, 0], sums[:, 1], rng)
        plain, plain_error = _ratio_with_error(sums[:, 2], sums[:, 3], rng)
        cells.append([place, int(sums[:, 4].sum()), f"{sums[:, 1].sum() / total_weight:.2f}",
                      f"{100 * weighted:+.3f} ± {100 * weighted_error:.3f}",
                      f"{100 * plain:+.3f} ± {100 * plain_error:.3f}"])
        if args.starts:
            for column in (5, 6):
                value, error = _ratio_with_error(sums[:, column], sums[:, 7], starts_rng)
                cells[-1].append(f"{100 * value:+.3f} ± {100 * error:.3f}")
    print(f"{name}: {args.seeds} seeds from 1, {args.duration:g} s each")
    print(table(cells, ["matches", "count", "share of the weight", "scale − 1, weighted %",
                        "scale − 1, unweighted %"]
                + ["KISS-ICP's answer, unweighted %", "refined from the true motion, unweighted %"]
                * args.starts))


if __name__ == "__main__":
    main()
