"""Where a noisy laser's scan matches come out short or long: straight-driving scan pairs of
the default drive, one factor at a time, with the same noise draws in every variant.

The calibrations of bench/sensor_matrix.py show the URG-04LX-like laser's matches short and
the low-cost laser's long. Here the pairs are those a recording matches: the laser poses of
the simulator's default drive (PowerBot, office, `--seeds` routes of `--duration` s), 0.3 s
apart (the matching period), where the robot drives straight (turning less than 0.02 rad
between them). Each pair is ray cast and given `--draws` noise draws; every variant of a
draw uses the same random numbers, so the differences between variants are paired. The
point-to-line refinement starts at the true motion, with the wall fit and range-limit
clearance the recording would get (the laser's range noise judged as RefinedScanMatcher
does). Per laser and variant: the error along the motion in % of the motion, weighed as the
graph weighs the matches (noise model + the refinement's covariance), mean over routes ±
its standard error; and its paired difference from the first variant (the pipeline as it
is).

Variants:
  - as the pipeline runs: the driver drops readings past range_max, lines within
    CLEAR_OF_LIMIT·σ of the limit are not paired;
  - without that clearance;
  - readings past range_max kept (a driver without the cut);
  - the cut in the later scan of the pair only (the earlier one keeps its readings);
  - the earlier scan's returns whose *true* range is within 4σ of the limit left out (only a
    simulator knows the true range);
  - noise-free scans with the wall-segment lines of noisy lasers, and with the 6-beam fit;
  - the earlier scan's returns whose true point lies within 0.3 m of a wall segment's end
    (corners, door frames, furniture edges) left out, with noise and noise-free;
  - without the laser's mixed pixels, without its dropouts (the URG-like laser has
    neither: its rows repeat the pipeline's).

Run: .venv/bin/python bench/range_limit_bias.py [--seeds 6] [--draws 3] [--duration 120] [--jobs 2]
"""
from __future__ import annotations

import argparse
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import POWERBOT_LASER_MOUNT, powerbot_route, table  # noqa: E402
from sensor_matrix import LOW_COST, URG, _standard_error  # noqa: E402

LASERS = {"URG-04LX-like (3 cm, 5.6 m, 240°)": URG,
          "low-cost (2 cm + 1 % of range, 12 m)": LOW_COST}
VARIANTS = {
    "as the pipeline runs": {},
    "without the range-limit clearance": {"clearance": False},
    "readings past range_max kept": {"cut": ()},
    "cut in the later scan only": {"cut": (1,)},
    "earlier scan: true range within 4σ of the limit left out": {"oracle": 4.0},
    "noise-free, wall-segment lines": {"noise_free": True},
    "noise-free, 6-beam wall fit": {"noise_free": True, "narrow": True},
    "earlier scan: returns within 0.3 m of a wall's end left out": {"ends": 0.3},
    "noise-free, wall-segment lines, the same left out": {"noise_free": True, "ends": 0.3},
    "without mixed pixels": {"mixed_pixels": False},
    "without dropouts": {"dropouts": False},
}
PERIOD = 0.3  # s between matched scans (frontend/decimation.py)
STRAIGHT = 0.02  # rad: at most this much turn between the two scans


def _pairs(world, laser_mount, duration, seed):
    """(earlier, later, true motion) laser poses of the straight-driving pairs of a route."""
    from sclam_ros.core import se2

    route = powerbot_route(world, duration, seed)
    times = np.arange(0.0, route.duration - PERIOD, PERIOD)
    laser = se2.compose(route.pose_at(times), laser_mount)
    motion = se2.between(laser[1:], laser[:-1])
    straight = (np.abs(motion[:, 2]) < STRAIGHT) & (np.hypot(motion[:, 0], motion[:, 1]) > 0.01)
    return laser[:-1][straight], motion[straight]


def _measure(true, model, rng, variant, which):
    """One scan's ranges as the variant's driver reports them (`which`: 0 earlier, 1 later)."""
    from sclam_ros.sim.sensors import _mix_edges

    ranges = np.array(true, float)
    normal = rng.standard_normal(ranges.shape)  # drawn in every variant: draws stay paired
    dropped = rng.random(ranges.shape) < model.dropout
    if variant.get("noise_free"):
        return np.where(ranges > model.range_max, np.inf, ranges)
    if model.mixed_pixels > 0.0 and variant.get("mixed_pixels", True):
        _mix_edges(ranges, model.mixed_pixels, np.random.default_rng(rng.integers(1 << 31)))
    hit = np.isfinite(ranges)
    ranges[hit] += (model.range_noise + model.range_noise_per_m * ranges[hit]) * normal[hit]
    if variant.get("dropouts", True):
        ranges[hit & dropped] = np.inf
    if which in variant.get("cut", (0, 1)):
        ranges[ranges > model.range_max] = np.inf
    return ranges


def _wall_ends(world):
    """KD-tree of the ends of the simulator's wall segments."""
    return cKDTree(np.concatenate([world.segments[:, :2], world.segments[:, 2:]]))


def _distance_to_wall_ends(wall_ends, pose, angles, ranges):
    """(N,) m: how far the true point of each beam (inf where there is none) lies from the
    nearest wall end (`_wall_ends`)."""
    hit = np.isfinite(ranges)
    r = np.where(hit, ranges, 0.0)
    c, s = np.cos(pose[2] + angles), np.sin(pose[2] + angles)
    points = np.column_stack([pose[0] + r * c, pose[1] + r * s])
    return np.where(hit, wall_ends.query(points)[0], np.inf)


def _laser_seed(job):
    """{variant: (Σ w·error along, Σ w·|motion|)} over one route's straight pairs."""
    label, laser, seed, draws, duration = job
    from sclam_ros.core import se2
    from sclam_ros.core.inputs import Scan
    from sclam_ros.frontend import point_to_line
    from sclam_ros.frontend.scan_matching import NoiseModel, scan_to_points
    from sclam_ros.sim.sensors import LaserModel
    from sclam_ros.sim.world import office_world

    world = office_world()
    model = LaserModel(beams=laser["beams"], range_noise=laser["range_noise"], **laser["laser"])
    angles = model.angles()
    start, motion = _pairs(world, POWERBOT_LASER_MOUNT, duration, seed)
    wall_ends = _wall_ends(world)

    def scan(ranges):
        return Scan(0.0, ranges, model.angle_min, model.angle_increment, model.range_min, np.inf)

    rng = np.random.default_rng(seed)
    noise, growth = point_to_line.judged_laser(
        [scan(_measure(world.raycast(p, angles, model.range_max), model, rng, {}, 0))
         for p in start[:30]])
    fit_noise = noise if point_to_line.NOISY_RANGE <= noise <= point_to_line.NOT_A_NOISE else None
    usable = model.range_max - point_to_line.CLEAR_OF_LIMIT * noise
    sums = {name: np.zeros(2) for name in VARIANTS}
    for k, (first, z_true) in enumerate(zip(start, motion)):
        # True ranges past the limit are kept (as no return) so that a driver without the cut
        # can report a noisy reading there.
        true = [world.raycast(p, angles, model.range_max + 1.0)
                for p in (first, se2.compose(first, z_true))]
        true = [np.where(t > model.range_max, np.inf, t) for t in true]
        near_end = _distance_to_wall_ends(wall_ends, first, angles, true[0])
        along = z_true[:2] / np.hypot(*z_true[:2])
        for draw in range(draws):
            for name, variant in VARIANTS.items():
                draw_rng = np.random.default_rng([seed, k, draw])
                earlier, later = (_measure(t, model, draw_rng, variant, i) for i, t in enumerate(true))
                if "oracle" in variant:
                    earlier[true[0] > model.range_max - variant["oracle"] * noise] = np.inf
                if "ends" in variant:
                    earlier[near_end < variant["ends"]] = np.inf
                earlier_scan = scan(earlier)
                reference = point_to_line.ReferenceScan.from_points(
                    scan_to_points(earlier_scan), None if variant.get("narrow") else fit_noise,
                    usable if variant.get("clearance", True) else np.inf,
                    beam_spacing=abs(earlier_scan.angle_increment),
                    growth=0.0 if variant.get("narrow") else growth)
                z, used, covariance = point_to_line.refine_with_covariance(
                    reference, scan_to_points(scan(later))[:, :2], z_true)
                if not used:
                    continue
                graph = np.diag(NoiseModel().sigmas(z) ** 2) + covariance
                weight = 1.0 / (along @ graph[:2, :2] @ along)
                sums[name] += weight * np.array([along @ (z[:2] - z_true[:2]), np.hypot(*z_true[:2])])
    return label, seed, {name: 100.0 * s[0] / s[1] for name, s in sums.items()}


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=6)
    ap.add_argument("--draws", type=int, default=3, help="noise draws per pair")
    ap.add_argument("--duration", type=float, default=120.0)
    ap.add_argument("--jobs", type=int, default=2)
    args = ap.parse_args()
    jobs = [(label, laser, seed, args.draws, args.duration)
            for label, laser in LASERS.items() for seed in range(1, args.seeds + 1)]
    with ProcessPoolExecutor(args.jobs) as pool:
        results = list(pool.map(_laser_seed, jobs))
    rows = []
    for label in LASERS:
        per_seed = [r for lab, _, r in results if lab == label]
        base = np.array([r["as the pipeline runs"] for r in per_seed])
        for name in VARIANTS:
            values = np.array([r[name] for r in per_seed])
            diff = values - base
            rows.append([label if name == "as the pipeline runs" else "", name,
                         f"{values.mean():+.3f} ± {_standard_error(values[:, None])[0]:.3f}",
                         "" if name == "as the pipeline runs"
                         else f"{diff.mean():+.3f} ± {_standard_error(diff[:, None])[0]:.3f}"])
    print(f"straight-driving scan pairs {PERIOD} s apart, {args.seeds} routes × {args.duration:.0f} s, "
          f"{args.draws} noise draws each; refinement from the true motion, weighed as the graph does")
    print(table(rows, ["laser", "variant", "error along the motion %", "minus the pipeline's %"]))


if __name__ == "__main__":
    main()
