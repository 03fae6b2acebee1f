"""Where the point-to-line refinement's reference walls sit, against the simulator's walls.

A scan match is refined by measuring each new return's distance to the previous scan's
wall lines (frontend/point_to_line.py). Each line passes through a residual origin: on a
noisy laser, where the reference return's beam meets the line fitted to its straight
segment (an "anchor", frontend/wall_segments.py), and the return itself off the segments
(point_to_line.OFF_SEGMENTS); on any other laser the return itself. If those origins sit
beyond or in front of the true walls, the matches come out long or short. Here the
reference scans of the default drive (PowerBot, office, `--seeds` routes of `--duration`
s, one scan every 0.3 s, turns included) are ray cast with each laser's noise model,
turned into reference scans as a recording's matcher does (range noise judged on the first
30 scans, the wall fit and range-limit clearance that follow from it), and every origin
the refinement would use is compared with the true wall along the line's normal (+: beyond
the wall, away from the laser). Per laser (its kind of origin) and per true range of the
return: mean offset in mm ± its standard error over all origins.

Run: .venv/bin/python bench/reference_bias.py [--seeds 4] [--duration 60] [--jobs 2]
"""
from __future__ import annotations

import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import POWERBOT_LASER_MOUNT, powerbot_route, seeds_arguments, table  # noqa: E402
from sensor_matrix import LOW_COST, ROWS, URG  # noqa: E402

LASERS = {"URG-04LX-like (3 cm, 5.6 m, 240°, 683 b)": URG,
          "5 cm (20 m, 360°, 360 b)": ROWS["10 Hz, 360°, 360 b, 20 m, 5 cm"],
          "low-cost (2 cm + 1 % of range, 12 m, 720 b)": LOW_COST,
          "  without mixed pixels": dict(LOW_COST, laser=dict(LOW_COST["laser"], mixed_pixels=0.0)),
          "  without mixed pixels and the 1 % of range": dict(
              LOW_COST, laser=dict(LOW_COST["laser"], mixed_pixels=0.0, range_noise_per_m=0.0))}
PERIOD = 0.3  # s between reference scans (the matching period, frontend/decimation.py)
BINS = ((0.0, 2.0), (2.0, 4.0), (4.0, 6.0), (6.0, np.inf))  # true range of the return, m


def _route_poses(world, duration, seed):
    """Laser poses of one simulated route, PERIOD apart."""
    from sclam_ros.core import se2

    route = powerbot_route(world, duration, seed)
    return se2.compose(route.pose_at(np.arange(0.0, route.duration, PERIOD)), POWERBOT_LASER_MOUNT)


def _offsets(job):
    """(true range (n,), offset (n,) m, judged noise m, anchored: the origins are anchors
    where there are segments, not only returns) of every residual origin of one route's
    reference scans."""
    seed, laser, duration = job
    from sclam_ros.core.inputs import Scan
    from sclam_ros.frontend import point_to_line
    from sclam_ros.frontend.scan_matching import scan_to_points
    from sclam_ros.sim.sensors import LaserModel
    from sclam_ros.sim.world import office_world

    world = office_world()
    model = LaserModel(beams=laser.get("beams", 360), range_noise=laser.get("range_noise", 0.01),
                       **laser.get("laser", {}))
    angles = model.angles()
    rng = np.random.default_rng(seed)
    poses = _route_poses(world, duration, seed)
    true = [world.raycast(p, angles, model.range_max) for p in poses]
    measured = [model.measure(t, rng) for t in true]
    scans = [Scan(0.0, r, model.angle_min, model.angle_increment, model.range_min, model.range_max)
             for r in measured]
    # The laser's noise judged as RefinedScanMatcher judges it, and what follows from it.
    noise, growth = point_to_line.judged_laser(scans)
    fit_noise = noise if point_to_line.NOISY_RANGE <= noise <= point_to_line.NOT_A_NOISE else None
    usable = model.range_max - (point_to_line.CLEAR_OF_LIMIT * noise if noise <= point_to_line.NOT_A_NOISE else 0.0)
    ranges, offsets = [], []
    for pose, scan in zip(poses, scans):
        points = scan_to_points(scan)[:, :2]
        reference = point_to_line.ReferenceScan.from_points(points, fit_noise, usable, growth=growth)
        if reference is None:
            continue
        origin = reference.anchors
        bearing = np.arctan2(origin[:, 1], origin[:, 0])
        wall = world.raycast(pose, bearing, 2.0 * model.range_max)  # true wall on the origin's bearing
        ok = np.isfinite(wall)
        wall_point = np.column_stack([wall * np.cos(bearing), wall * np.sin(bearing)])
        away = np.sign(np.sum(reference.normals * origin, axis=1))  # normal oriented away from the laser
        offset = np.sum((origin - wall_point) * reference.normals, axis=1) * away
        ranges.append(wall[ok])  # the true range on the origin's beam
        offsets.append(offset[ok])
    return np.concatenate(ranges), np.concatenate(offsets), noise, fit_noise is not None


def main():
    args = seeds_arguments(__doc__, seeds=4, duration=60.0).parse_args()
    rows = []
    with ProcessPoolExecutor(args.jobs) as pool:
        for label, laser in LASERS.items():
            runs = list(pool.map(_offsets, [(seed, laser, args.duration) for seed in range(1, args.seeds + 1)]))
            true_range, offset = (np.concatenate([r[i] for r in runs]) for i in range(2))
            noise = np.median([r[2] for r in runs])
            cells = []
            for lo, hi in BINS:
                m = (true_range >= lo) & (true_range < hi)
                cells.append(f"{1e3 * offset[m].mean():+.2f} ± {1e3 * offset[m].std() / np.sqrt(m.sum()):.2f}"
                             if m.sum() >= 50 else "–")
            kinds = {"segment anchor, own return off segments" if r[3] else "own return" for r in runs}
            origin = " or ".join(sorted(kinds))  # per route, as each judges the noise
            rows.append([label, f"{1e3 * noise:.0f}", origin, *cells])
    print(f"{args.seeds} routes × {args.duration:.0f} s, a reference scan every {PERIOD} s; offset of the "
          "residual origin from the true wall along the line's normal, mm (+: beyond the wall)")
    print(table(rows, ["laser", "judged noise mm", "origin",
                       *(f"{lo:g}–{hi:g} m" if np.isfinite(hi) else f"≥ {lo:g} m" for lo, hi in BINS)]))


if __name__ == "__main__":
    main()
