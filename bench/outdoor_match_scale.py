"""Which of the outdoor scene's objects makes its scan matches long, and where in the front end.

The sensor matrix's outdoor row (bench/sensor_matrix.py) calibrates the radii about 0.15 %
large because its scan matches come out long. Here the matches of the same recordings
(PowerBot, the default laser, the default drive, --duration s, seeds 1..--seeds) are compared
with the truth three ways, each match weighted by w, the x-x element of its information
matrix (its precision along the laser's x given y and θ; the graph uses the whole matrix):
Σ w z·z_true / Σ w |z_true|² per recording, then mean ± standard error over the seeds.
The scale depends on that weighting: on the same pairs, weighting each by the along-track
variance of its own refinement from the truth gave 1.0010 ± 0.0011 (ad hoc, square
trunks), unweighted 1.0070 ± 0.0029. Compare the rows, not the numbers with 1:

  - KISS-ICP's raw answer;
  - the refined z the graph uses (point_to_line, after confirmation);
  - the refinement started at the true motion on the same two scans: where the refinement
    settles by itself, independent of its start and of which matches it confirms.

Scene variants, one factor at a time (the simulator's outdoor world with its builders
replaced for the run): as simulated (tree trunks as octagons), trunks as 32-gons (rounder),
trunks as square boxes of the same width (flat faces and corners), without the trunks, without the parked cars (the poles, 0.15 m boxes, and the façade stay). Also: the refined scale by
the length of the true motion (the step), all seeds pooled.

The front end is observed, not changed: point_to_line._confirmed is wrapped to record each
match's reference scan, points and KISS-ICP answer (common.observed_refinements).

Run: .venv/bin/python bench/outdoor_match_scale.py [--seeds 8] [--duration 120] [--jobs 2]
"""
from __future__ import annotations

import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import observed_refinements, scratch_dir, seeds_arguments, table  # noqa: E402

VARIANTS = ("as simulated (trunks as octagons)", "trunks as 32-gons", "trunks as square boxes",
            "without the trunks", "without the parked cars")
STEP_BINS = ((0.0, 0.03), (0.03, 0.08), (0.08, 0.15), (0.15, 1.0))


def scene_variant(variant):
    """Replace the outdoor world's object builders for this process's run (and the processes
    it forks); returns a function that puts them back."""
    from sclam_ros.sim import world

    octagon, box = world._octagon, world._box
    if variant == VARIANTS[1]:
        def round_object(cx, cy, radius):
            angles = np.linspace(0.0, 2.0 * np.pi, 33)
            return world._polyline(*[(cx + radius * np.cos(a), cy + radius * np.sin(a)) for a in angles])
        world._octagon = round_object
    elif variant == VARIANTS[2]:
        world._octagon = lambda cx, cy, radius: box(cx, cy, 2.0 * radius, 2.0 * radius)
    elif variant == VARIANTS[3]:
        world._octagon = lambda cx, cy, radius: []
    elif variant == VARIANTS[4]:
        world._box = lambda cx, cy, w, h: [] if w > 1.0 else box(cx, cy, w, h)
    return lambda: (setattr(world, "_octagon", octagon), setattr(world, "_box", box))


def run_case(job):
    """(variant, seed, rows): per confirmed match (information weight, true z, refined z,
    KISS-ICP z, z refined from the truth)."""
    variant, seed, duration, workdir = job
    from sclam_ros.core import se2
    from sclam_ros.core.params import SclamParams
    from sclam_ros.frontend import point_to_line
    from sclam_ros.io.recording import read_ground_truth, read_recording
    from sclam_ros.sim import simulate

    restore = scene_variant(variant)
    try:
        with observed_refinements() as calls:
            bag = Path(workdir) / f"{VARIANTS.index(variant)}_{seed}"
            truth = simulate(bag, duration=duration, seed=seed, overwrite=True, scene="outdoor")
            params = SclamParams.from_yaml(bag / "params.yaml")
            keyframes = read_recording(bag, params).keyframes
            stamps_gt, poses_gt = read_ground_truth(bag)
    finally:
        restore()
    mount = np.array([truth["laser_x"], truth["laser_y"], truth["laser_yaw"]])
    heading = np.unwrap(poses_gt[:, 2])

    def laser_at(t):
        pose = np.array([np.interp(t, stamps_gt, poses_gt[:, 0]), np.interp(t, stamps_gt, poses_gt[:, 1]),
                         np.interp(t, stamps_gt, heading)])
        return se2.compose(pose, mount)

    by_z = {tuple(np.round(kf.laser_motion, 12)): kf for kf in keyframes if kf.laser_motion is not None}
    stamp = {kf.index: kf.stamp for kf in keyframes}
    rows = []
    for reference, points, z_icp, (z, _, reason) in calls:
        kf = None if reason else by_z.get(tuple(np.round(z, 12)))
        if kf is None or kf.laser_from not in stamp:
            continue
        z_true = se2.between(laser_at(kf.stamp), laser_at(stamp[kf.laser_from]))
        from_truth, used, _ = point_to_line.refine_with_covariance(reference, points, z_true)
        rows.append((kf.laser_information[0, 0], z_true, z, z_icp,
                     from_truth if used else np.full(3, np.nan)))
    return variant, seed, rows


def _scale(rows, which, mask=None):
    """Information-weighted Σ w z·z_true / Σ w |z_true|² of column `which` (nan without
    rows: a recording none of whose matches the refinement confirmed)."""
    if not rows:
        return np.nan
    w = np.array([r[0] for r in rows])
    z_true = np.array([r[1] for r in rows])
    z = np.array([r[which] for r in rows])
    keep = np.all(np.isfinite(z), axis=1) if mask is None else mask & np.all(np.isfinite(z), axis=1)
    if not keep.any():
        return np.nan
    return float(np.sum(w[keep] * np.sum(z[keep, :2] * z_true[keep, :2], 1))
                 / np.sum(w[keep] * np.sum(z_true[keep, :2] ** 2, 1)))


def _mean_se(values):
    values = np.asarray([v for v in values if np.isfinite(v)])
    return f"{values.mean():.4f} ± {values.std(ddof=1) / np.sqrt(len(values)):.4f}"


def main():
    args = seeds_arguments(__doc__, seeds=8, duration=120.0).parse_args()
    work = scratch_dir("sclam_outdoor_scale_")
    jobs = [(v, s, args.duration, work) for v in VARIANTS for s in range(1, args.seeds + 1)]
    with ProcessPoolExecutor(args.jobs) as pool:
        results = list(pool.map(run_case, jobs))
    by_variant = {v: [rows for variant, _, rows in results if variant == v] for v in VARIANTS}
    print(f"outdoor scene, default laser, {args.seeds} seeds × {args.duration:g} s; scale of the "
          f"matched translations against the truth, weighted by each match's x-x information, "
          f"mean ± s.e. over seeds")
    print(table([[v, sum(len(r) for r in runs)] + [_mean_se([_scale(r, k) for r in runs]) for k in (3, 2, 4)]
                 for v, runs in by_variant.items()],
                ["scene", "matches", "KISS-ICP raw", "refined (used)", "refined from the truth"]))
    pooled = [row for rows in by_variant[VARIANTS[0]] for row in rows]
    step = np.array([np.hypot(*r[1][:2]) for r in pooled])
    along = np.array([(r[2][:2] - r[1][:2]) @ r[1][:2] / max(np.hypot(*r[1][:2]), 1e-9) for r in pooled])
    print(f"\n{VARIANTS[0]}, all seeds pooled: refined error along the true motion, by its length")
    print(table([[f"{lo * 100:.0f}-{hi * 100:.0f} cm", int(np.sum((step >= lo) & (step < hi))),
                  f"{1e3 * np.median(along[(step >= lo) & (step < hi)]):+.2f}",
                  f"{1e3 * np.mean(along[(step >= lo) & (step < hi)]):+.2f}",
                  f"{_scale(pooled, 2, (step >= lo) & (step < hi)):.4f}"]
                 for lo, hi in STEP_BINS],
                ["step", "matches", "median error mm", "mean error mm", "weighted scale"]))


if __name__ == "__main__":
    main()
