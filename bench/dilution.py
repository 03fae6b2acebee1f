"""The wheel base's regression dilution and its correction (sclam_ros/core/dilution.py), on
graphs drawn from the generative model itself (test/synthetic.py: no scans, no ICP, the
noise exactly as stated), where the only bias is the one the correction is for.

    .venv/bin/python bench/dilution.py [--seeds 40] [--duration 60] [--jobs 2]

Per slip level: drives of --duration s (one edge per 0.1 s, straights and turns both ways), the
encoders' angles with slip noise σ = level·sqrt(angle turned), scan matches 2 mm / 1 mrad;
each calibrated by the product's graph (graph.build_problem, variance components) without
and with the correction, and the same drives and scan-match noise without slip. Printed:
mean error of r_l, r_r, b in % ± the standard error over the seeds; the wheel base's error
less that of the same seed without slip (the slip's part: the dilution, and what the
correction leaves of it); on how many seeds the correction was applied (it is not where it
would move k by more than 1 %).
"""
from __future__ import annotations

import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "test"))
sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import seeds_arguments, table  # noqa: E402

# rad/sqrt(rad): the simulator's default (0.5 % of a revolution per revolution) and larger.
SLIP_LEVELS = (0.005 * np.sqrt(2 * np.pi), 0.025, 0.04)
NO_SLIP = 1e-6
NOMINAL = np.array([0.125, 0.125, 0.56, 0.22, 0.0, 0.0])
EDGE_SECONDS = 0.1


def calibrate(args):
    """k's error in % without and with the correction, and the correction's (shift %, applied)."""
    from synthetic import make_graph

    from sclam_ros.core import graph
    from sclam_ros.core.params import SclamParams
    from sclam_ros.core.variance_components import solve_with_variance_components

    slip, seed, poses = args
    g = make_graph(n=poses, seed=1000 + seed, wheel_noise=slip)
    edges = np.arange(poses - 1)
    info = np.tile(np.diag(g["laser_sigma"] ** -2.0), (poses - 1, 1, 1))
    inputs = graph.GraphInputs(np.arange(poses) * EDGE_SECONDS, edges, g["dphi"], edges,
                               edges + 1, g["z"], info)
    params = SclamParams(wheel_radius_left=NOMINAL[0], wheel_radius_right=NOMINAL[1],
                         wheel_base=NOMINAL[2], laser_x=NOMINAL[3], wheel_noise=slip)
    errors, correction = [], None
    for correct in (False, True):
        problem = graph.build_problem(inputs, params, NOMINAL, correct_dilution=correct)
        result, _ = solve_with_variance_components(problem)
        k = result.values["odometry"][0]
        errors.append(100.0 * (k - g["k"]) / g["k"])
        if correct:
            found = problem.corrections[0]
            correction = (100.0 * found.shift[2] / k[2], found.active)
    return errors, correction


def _mean(values, digits=3) -> str:
    """Mean of each column ± its standard error over the seeds."""
    values = np.asarray(values)
    se = values.std(0, ddof=1) / np.sqrt(len(values))
    return (" ".join(f"{m:+.{digits}f}" for m in values.mean(0)) + " (± "
            + " ".join(f"{s:.{digits}f}" for s in se) + ")")


def main(argv=None):
    ap = seeds_arguments(__doc__, 40, 60.0)
    args = ap.parse_args(argv)
    poses = int(round(args.duration / EDGE_SECONDS)) + 1
    seeds = range(1, args.seeds + 1)
    rows = []
    with ProcessPoolExecutor(args.jobs) as pool:
        # The same drives and scan-match noise without slip: what the graph makes of them
        # apart from the wheel noise (the incidental poses' own small bias), subtracted
        # seed by seed below.
        still = np.array([r[0][0] for r in pool.map(calibrate, [(NO_SLIP, s, poses) for s in seeds])])
        rows.append([f"{NO_SLIP:g}", _mean(still), "", "", "", ""])
        for slip in SLIP_LEVELS:
            runs = list(pool.map(calibrate, [(slip, s, poses) for s in seeds]))
            plain = np.array([r[0][0] for r in runs])
            corrected = np.array([r[0][1] for r in runs])
            applied = sum(r[1][1] for r in runs)
            rows.append([f"{slip:.4f}", _mean(plain), _mean(corrected),
                         _mean((plain - still)[:, 2:]), _mean((corrected - still)[:, 2:]),
                         f"{applied}/{len(runs)}"])
            print(f"slip {slip:.4f} done", file=sys.stderr, flush=True)
    print(table(rows, ["slip rad/√rad", "least squares: r_l r_r b % (± s.e.)",
                       "corrected: r_l r_r b % (± s.e.)", "b: least squares − without slip %",
                       "b: corrected − without slip %", "corrected on"]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
