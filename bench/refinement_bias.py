"""Does the point-to-line refinement settle on the true motion? Its bias on scan pairs with known motion.

A calibration's scale comes from the average of many scan matches, so a refinement whose
fixed point sits 0.1 % long moves the wheel radii by 0.1 % although each match is within
its σ. That is too small to see on one recording (bench/sensor_matrix.py needs tens of
seeds to resolve it); here it is measured where nothing else can be blamed:

  - pairs of laser poses in the simulator's office (or outdoor scene), the second `--step` m ahead of the
    first along the laser's x axis (the robot's usual motion between matched scans) and
    turned by a random few degrees; both scans ray cast, then `--draws` noise draws per pair;
  - the refinement (point_to_line.refine_with_covariance) started at the true motion, with
    the wall-line fit a recording would choose for that laser (its median range_noise over
    30 noisy scans, as RefinedScanMatcher judges it) and the lines near the range limit
    left out as it does (point_to_line.CLEAR_OF_LIMIT);
  - the error along the motion, as % of the step: the mean over pairs (± standard error
    over pairs); the mean weighted by each match's information along the motion as the
    graph weighs the matches, from the scan-match noise model's covariance plus the
    refinement's own (scan_matching.NoiseModel, point_to_line.refine_with_covariance)
    (± standard error by resampling the pairs); and the 5–95 % range of the per-pair means
    (mm), which shows how much of it depends on the walls in view.

Rows: the low-cost laser of bench/sensor_matrix.py (2 cm + 1 % of range, 12 m, 720 beams;
no dropouts or mixed pixels, which only thin the scans), its noise in one scan of the pair
only, its residuals measured from the reference's returns instead of from where their
beams meet their wall lines, a wider Huber scale, a start 1 % long, constant-noise lasers,
the URG-04LX-like laser (started long, without the returns near its range limit, with a
longer range), the default laser in the office and outdoors. Rows 17-21: pairs along the
office corridor instead of the route's (the laser on the corridor's centre line heading
along it), with the 6-beam line fit a 1 cm laser gets in the last. Rows 22-23: the
URG-04LX-like laser on routes through the corridors scene (bare corridors between lobbies),
as recorded and on noise-free returns with the noisy laser's lines (their geometry alone).
Rows 24-25: the low-cost laser's returns weighed alike, not by the range noise that grows
with range (point_to_line.GROWTH), on the route's pairs and along the corridor.

Run: .venv/bin/python bench/refinement_bias.py [--pairs 600] [--draws 20] [--step 0.15] [--jobs 2]
     [--rows N ...]
"""
from __future__ import annotations

import argparse
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import table  # noqa: E402

MOUNT = np.array([0.15, -0.03, np.deg2rad(4.0)])  # laser on base_link, as the simulator's default
LOW_COST = dict(beams=720, range_noise=0.02, range_max=12.0, range_noise_per_m=0.01)
URG = dict(beams=683, range_noise=0.03, range_max=5.6, fov=np.radians(240.0))
CONSTANT_5_5 = dict(LOW_COST, range_noise=0.055, range_noise_per_m=0.0)  # the low-cost's judged noise
# (label, LaserModel keywords, noise in (reference, new) scan, point_to_line constants and
# start_scale: the refinement's start × the true motion; clear_of_limit: returns within
# this many σ of range_max left out, where the driver's cut makes the noise one-sided)
ROWS = [
    ("low-cost: 2 cm + 1 % of range, 12 m, 720 b", LOW_COST, (1.0, 1.0), {}),
    ("  noise in the new scan only", LOW_COST, (0.0, 1.0), {}),
    ("  noise in the reference scan only", LOW_COST, (1.0, 0.0), {}),
    ("  residuals from the returns (not where their beams meet their lines)", LOW_COST, (1.0, 1.0),
     {"origins": "returns"}),
    ("  Huber scale 0.2 m (10×)", LOW_COST, (1.0, 1.0), {"HUBER": 0.2}),
    ("  started 1 % long (as from a long KISS-ICP answer)", LOW_COST, (1.0, 1.0),
     {"start_scale": 1.01}),
    ("constant 6 cm, 12 m, 720 b", dict(LOW_COST, range_noise=0.06, range_noise_per_m=0.0),
     (1.0, 1.0), {}),
    ("constant 2 cm, 12 m, 720 b", dict(LOW_COST, range_noise_per_m=0.0), (1.0, 1.0), {}),
    ("URG-04LX-like: 3 cm, 5.6 m, 240°, 683 b", URG, (1.0, 1.0), {}),
    ("  started 1 % long", URG, (1.0, 1.0), {"start_scale": 1.01}),
    ("  returns within 3σ of the range limit left out", URG, (1.0, 1.0), {"clear_of_limit": 3.0}),
    ("  with a 20 m range", dict(URG, range_max=20.0), (1.0, 1.0), {}),
    # The outdoor scene (trunks and poles as octagons, parked cars, one façade) with the
    # default laser: where the sensor matrix's outdoor matches come out long.
    ("office, default laser: 1 cm, 20 m, 360 b", {}, (1.0, 1.0), {}),
    ("outdoor scene, default laser: 1 cm, 20 m, 360 b", {}, (1.0, 1.0), {"scene": "outdoor"}),
    ("  without noise (the scene's geometry alone)", {}, (0.0, 0.0), {"scene": "outdoor"}),
    ("  started 1 % long", {}, (1.0, 1.0), {"scene": "outdoor", "start_scale": 1.01}),
    ("  720 beams", dict(beams=720), (1.0, 1.0), {"scene": "outdoor"}),
    # Pairs along the office corridor (the laser on its centre line, ±0.2 m, heading along
    # it), where a drive's matches come out longest.
    ("low-cost, pairs along the corridor", LOW_COST, (1.0, 1.0), {"pairs": "corridor"}),
    ("  noise in the new scan only", LOW_COST, (0.0, 1.0), {"pairs": "corridor"}),
    ("  noise in the reference scan only", LOW_COST, (1.0, 0.0), {"pairs": "corridor"}),
    ("constant 5.5 cm along the corridor, noise in the reference only", CONSTANT_5_5, (1.0, 0.0),
     {"pairs": "corridor"}),
    ("  lines fitted over 6 beams (as for a 1 cm laser)", CONSTANT_5_5, (1.0, 0.0),
     {"pairs": "corridor", "fit": "narrow"}),
    ("URG-04LX-like, corridors scene", URG, (1.0, 1.0), {"scene": "corridors"}),
    ("  without noise, its lines fitted as for 3 cm (their geometry alone)", URG, (0.0, 0.0),
     {"scene": "corridors", "fit": "noisy"}),
    # The low-cost laser's returns weighed alike instead of by their range noise, which
    # grows with range (point_to_line.GROWTH): on the route's pairs and along the corridor.
    ("low-cost, returns weighed alike (not by their range noise)", LOW_COST, (1.0, 1.0),
     {"alike": True}),
    ("low-cost along the corridor, returns weighed alike", LOW_COST, (1.0, 1.0),
     {"pairs": "corridor", "alike": True}),
]


def _scan(ranges, model):
    from sclam_ros.core.inputs import Scan

    return Scan(0.0, ranges, model.angle_min, model.angle_increment, model.range_min, model.range_max)


def _measured(true, model, which, rng):
    """The scans' ranges with the model's noise scaled by `which` (per scan), dropped
    beyond range_max as a driver does."""
    with np.errstate(invalid="ignore"):  # no return (inf) × a scan without noise (0)
        sigma = model.range_noise + model.range_noise_per_m * true
        ranges = true + np.asarray(which)[:, None] * sigma * rng.standard_normal(true.shape)
        ranges[~np.isfinite(ranges) | (ranges > model.range_max) | (ranges < model.range_min)] = np.inf
    return ranges


def run_row(job):
    """_measure_row with the row's point_to_line constants set, and put back after it (a
    pool process runs several rows)."""
    from sclam_ros.frontend import point_to_line

    constants = {k: v for k, v in job[3].items() if k.isupper() and hasattr(point_to_line, k)}
    saved = {k: getattr(point_to_line, k) for k in constants}
    try:
        for name, value in constants.items():
            setattr(point_to_line, name, value)
        return _measure_row(job)
    finally:
        for name, value in saved.items():
            setattr(point_to_line, name, value)


def _measure_row(job):
    """(label, mean % and its s.e., weighted mean % and its s.e., 5 % and 95 % of the
    per-pair means in mm, matches used, judged noise in m)."""
    label, laser, which, options, pairs, draws, step, seed = job
    from sclam_ros.core import se2
    from sclam_ros.frontend import point_to_line
    from sclam_ros.frontend.scan_matching import NoiseModel, scan_to_points
    from sclam_ros.sim.motion import TrueKinematics
    from sclam_ros.sim.sensors import LaserModel
    from sclam_ros.sim.trajectory import simulate_trajectory
    from sclam_ros.sim.world import scene_world

    start_scale = options.get("start_scale", 1.0)  # the refinement's start, × the true motion
    clear_of_limit = options.get("clear_of_limit", 0.0)  # σ: returns this near range_max left out
    scene = options.get("scene", "office")
    world = scene_world(scene)
    route = simulate_trajectory(world, TrueKinematics(0.1, 0.1, 0.5), 200.0, seed, robot_radius=0.3)
    rng = np.random.default_rng(seed)
    model = LaserModel(**laser)
    angles = model.angles()
    if options.get("pairs") == "corridor":
        laser_poses = _corridor_poses(world, pairs, rng)
    else:
        laser_poses = se2.compose(route.pose_at(rng.uniform(0.0, route.duration - 1.0, pairs)), MOUNT)
    # The wall-line fit the recording would choose: the laser's own noise, judged as
    # RefinedScanMatcher does (median over 30 scans), whichever scan carries noise here.
    judging = [_scan(model.measure(world.raycast(p, angles, model.range_max)[None], rng)[0], model)
               for p in laser_poses[:30]]
    noise, growth = point_to_line.judged_laser(judging)
    fit_noise = noise if point_to_line.NOISY_RANGE <= noise <= point_to_line.NOT_A_NOISE else None
    if options.get("alike"):  # the returns weighed alike, not by a noise growing with range
        growth = 0.0
    if options.get("fit") == "narrow":
        fit_noise = None
    elif options.get("fit") == "noisy":  # noise-free returns, the laser model's noise's lines
        noise = fit_noise = model.range_noise
    # Lines near the range limit are left out as RefinedScanMatcher does (CLEAR_OF_LIMIT).
    usable_range = model.range_max - (point_to_line.CLEAR_OF_LIMIT * noise
                                      if noise <= point_to_line.NOT_A_NOISE else 0.0)
    per_pair, used = [], 0
    for first in laser_poses:
        second = se2.compose(first, np.array([step, 0.0, rng.normal(0.0, 0.05)]))
        true = np.array([world.raycast(p, angles, model.range_max) for p in (first, second)])
        z_true = se2.between(second, first)
        along = z_true[:2] / np.hypot(*z_true[:2])
        errors, weights = [], []
        for _ in range(draws):
            ranges = _measured(true, model, which, rng)
            if clear_of_limit:
                ranges[ranges > model.range_max - clear_of_limit * noise] = np.inf
            earlier_scan = _scan(ranges[0], model)
            if options.get("origins") == "returns":
                reference = _from_returns(earlier_scan, fit_noise, usable_range, growth)
            else:
                reference = point_to_line.ReferenceScan.from_points(
                    scan_to_points(earlier_scan), fit_noise, usable_range,
                    small_objects=noise >= point_to_line.SMALL_OBJECT_NOISE,
                    beam_spacing=abs(earlier_scan.angle_increment),
                    growth=growth)
            points = scan_to_points(_scan(ranges[1], model))[:, :2]
            z, pairs_used, covariance = point_to_line.refine_with_covariance(
                reference, points, z_true * [start_scale, start_scale, 1.0])
            if pairs_used:
                errors.append(along @ (z[:2] - z_true[:2]))
                # The graph's covariance of the match: the noise model's plus the refinement's.
                graph_covariance = np.diag(NoiseModel().sigmas(z) ** 2) + covariance
                weights.append(1.0 / (along @ graph_covariance[:2, :2] @ along))
        if errors:
            per_pair.append((np.mean(errors), np.sum(np.multiply(weights, errors)), np.sum(weights)))
            used += len(errors)
    per_pair = np.array(per_pair)
    means = per_pair[:, 0]
    mean = 100.0 * means.mean() / step
    error = 100.0 * means.std(ddof=1) / np.sqrt(len(means)) / step
    low, high = 1e3 * np.percentile(means, [5, 95])
    # As the graph weighs them: by their information along the motion (a match in a
    # corridor whose ends are out of range counts little); its standard error by
    # resampling the pairs.
    weighted = 100.0 * per_pair[:, 1].sum() / per_pair[:, 2].sum() / step
    resampled = rng.integers(0, len(per_pair), (200, len(per_pair)))
    spread = 100.0 * np.std(per_pair[resampled, 1].sum(1) / per_pair[resampled, 2].sum(1)) / step
    return label, mean, error, weighted, spread, low, high, used, noise


def _corridor_poses(world, count, rng):
    """Laser poses on the office corridor's centre line (±0.2 m), heading along it either
    way (±2°), between its end nodes."""
    corridor = np.array([xy for name, xy in world.nodes.items() if name.startswith("corridor")])
    x = rng.uniform(corridor[:, 0].min(), corridor[:, 0].max(), count)
    y = corridor[0, 1] + rng.normal(0.0, 0.2, count)
    heading = rng.choice([0.0, np.pi], count) + rng.normal(0.0, np.radians(2.0), count)
    return np.column_stack([x, y, heading])


def _from_returns(scan, fit_noise, usable_range, growth):
    """The reference of `scan` with its lines as a recording fits them, paired with and its
    residuals measured from the returns themselves."""
    from sclam_ros.frontend import point_to_line
    from sclam_ros.frontend.scan_matching import scan_to_points

    points = scan_to_points(scan)[:, :2]
    normals, _, keep = point_to_line.line_decisions(points, fit_noise, usable_range,
                                                    growth=growth)
    reference = point_to_line.ReferenceScan.of_kept(points, normals, points, keep, usable_range)
    if reference is not None and growth:  # weighed by their neighbours' ranges (own_ranges)
        reference.growth = growth
        reference.own_ranges = point_to_line.neighbours_range(points, np.flatnonzero(keep))
    return reference


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--pairs", type=int, default=600)
    ap.add_argument("--draws", type=int, default=20, help="noise draws per pair")
    ap.add_argument("--step", type=float, default=0.15, help="m between the two laser poses")
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--rows", type=int, nargs="*", help="row numbers (from 0) to run; default all")
    args = ap.parse_args()
    rows = [ROWS[i] for i in args.rows] if args.rows else ROWS
    jobs = [(label, laser, which, constants, args.pairs, args.draws, args.step, args.seed)
            for label, laser, which, constants in rows]
    with ProcessPoolExecutor(args.jobs) as pool:
        results = list(pool.map(run_row, jobs))
    print(f"{args.pairs} pose pairs × {args.draws} noise draws, {args.step:g} m apart, office unless "
          f"said; refinement started at the true motion")
    print(table([[label, f"{mean:+.3f} ± {error:.3f}", f"{weighted:+.3f} ± {spread:.3f}",
                  f"{low:+.2f} … {high:+.2f}", used, f"{1e3 * noise:.0f}"]
                 for label, mean, error, weighted, spread, low, high, used, noise in results],
                ["laser / variant", "error along the motion % (± s.e.)",
                 "weighted by the match's information %", "per pair 5–95 % (mm)",
                 "matches", "judged noise mm"]))


if __name__ == "__main__":
    main()
