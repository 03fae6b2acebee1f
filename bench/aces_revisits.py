"""An experiment on ACES, not a calibration anyone should use: would loop closures make
the wheels' calibration keep the heading over minutes (docs/real_data.md)?

The ground truth's own relations that span SPAN s or more with a translation under DIST m
are revisits, checked by hand by the benchmark's authors: the best loop closures there
can be. Each becomes one more laser edge between the graph's nearest keyframes (σ 5 cm,
0.5°, the laser taken at the base's origin as the log states), and the log is calibrated
again. The relation table then scores it as bench/real_data.py does; the ≥ 10 s rows share
relations with the closures, so the graph's poses are not an independent check there.
What the experiment asks is only where b / r_r and r_l / r_r go.

Slow: the closures widen the pose band, and the covariances go through a sparse LU
(about 15 minutes on 2 cores).

Run: .venv/bin/python bench/aces_revisits.py [DATA_DIR] [--span 30] [--dist 2]
"""
from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import scratch_dir, table  # noqa: E402
from real_data import ROOT, odometry_ratios, ratios_from_relations, relation_rows  # noqa: E402

from sclam_ros.core import estimator, factors, graph  # noqa: E402
from sclam_ros.core.params import SclamParams  # noqa: E402
from sclam_ros.io import carmen, relations  # noqa: E402
from sclam_ros.io.convert import convert_carmen  # noqa: E402
from sclam_ros.io.recording import read_recording  # noqa: E402

SCAN_DELAY = 0.1  # s, docs/real_data.md
CLOSURE_SIGMA = np.array([0.05, 0.05, math.radians(0.5)])  # m, m, rad


def nearest(stamps, at):
    i = np.clip(np.searchsorted(stamps, at), 1, len(stamps) - 1)
    return i - ((at - stamps[i - 1]) < (stamps[i] - at))


def with_closures(closures):
    """graph.build_problem with the closures as extra laser edges between the keyframes
    nearest their times (within 0.2 s)."""
    build = graph.build_problem

    def build_problem(inputs, params, calibration, **kwargs):
        i, j = nearest(inputs.stamps, closures[:, 0]), nearest(inputs.stamps, closures[:, 1])
        near = ((np.abs(inputs.stamps[i] - closures[:, 0]) < 0.2)
                & (np.abs(inputs.stamps[j] - closures[:, 1]) < 0.2))
        info = np.tile(np.diag(CLOSURE_SIGMA ** -2.0), (int(near.sum()), 1, 1))
        edge = factors.LaserFactor(i[near], j[near], closures[near, 2:5], info)
        kwargs["extra_factors"] = (*kwargs.get("extra_factors", ()), edge)
        return build(inputs, params, calibration, **kwargs)
    return build_problem


def main(argv) -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("data", nargs="?", type=Path, default=ROOT.parent / "shared" / "data")
    ap.add_argument("--span", type=float, default=30.0, help="s, the shortest revisit")
    ap.add_argument("--dist", type=float, default=2.0, help="m, the farthest revisit")
    args = ap.parse_args(argv[1:])
    src = args.data / "freiburg-aces" / "aces.clf.bz2"
    if not src.exists():
        print(f"freiburg-aces not found under {args.data}; skipped")
        return 0
    out = scratch_dir("aces_revisits_") / "aces"
    convert_carmen(src, out, scan_delay=SCAN_DELAY, fov=carmen.FLASER_FOV)
    params = SclamParams.from_yaml(out / "params.yaml")
    recording = read_recording(out / "bag", params)
    log = carmen.read_carmen(src)
    rel = relations.read_relations(args.data / "freiburg-aces" / "aces.relations")
    rel[:, :2] -= SCAN_DELAY
    revisit = ((rel[:, 1] - rel[:, 0] >= args.span)
               & (np.hypot(rel[:, 2], rel[:, 3]) < args.dist))
    truth = ratios_from_relations(log, rel)[0]
    results = {"as sclam calibrate": estimator.calibrate_keyframes(
        recording.keyframes, params, recording.rejections)}
    graph.build_problem = with_closures(rel[revisit])
    results[f"+ {int(revisit.sum())} revisits as closures"] = estimator.calibrate_keyframes(
        recording.keyframes, params, recording.rejections)
    rows = []
    for label, result in results.items():
        ratio, base_ratio, sigma = odometry_ratios(result)
        errors = relation_rows(log, rel, {"whole": result}, [0.1, 0.1, 0.4], {})
        rows.append([label, f"{ratio:.5f} ± {sigma[0]:.5f}", f"{base_ratio:.4f} ± {sigma[1]:.4f}",
                     *errors[2][1:3], *errors[3][1:3], str(result.converged)])
    rows.append(["relations ≥ 10 s (fit)", f"{truth[0]:.5f}", f"{truth[1]:.4f}", "", "", "", "", ""])
    print(table(rows, ["calibration", "r_l / r_r", "b / r_r", "wheels ≥ 10 s m", "deg",
                       "graph poses ≥ 10 s m", "deg", "converged"]))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
