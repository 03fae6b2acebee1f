"""How a laser's range noise grows with range, as the front end judges it from a recording's first scans.

The point-to-line refinement weighs each return by 1/σ(r)² where a noisy laser's range noise
grows with range (point_to_line.GROWTH). The growth is measured, not configured:
RefinedScanMatcher pools point_to_line.range_errors of its first NOISE_SCANS reference scans
and point_to_line.judged_growth fits σ(r) = a + b·r to them, growth = b/a (0 where σ does
not grow enough over the ranges seen to matter). Here the same judgement runs on the first
30 scans, 0.3 s apart, of each of `--drives` random routes per scene, for the sensor
matrix's noisy lasers (bench/sensor_matrix.py: the URG-04LX-like, 5 cm and low-cost lasers,
the last with its dropouts and mixed pixels), indoors and outdoors; the simulator's truth
for the low-cost laser is 0.01 / 0.02 = 0.5 per metre, for the others 0.

Run: .venv/bin/python bench/noise_growth.py [--drives 40]
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import table  # noqa: E402

MOUNT = np.array([0.15, -0.03, np.deg2rad(4.0)])  # laser on base_link, as the simulator's default
LASERS = {  # name: (LaserModel keywords, the simulator's growth per metre)
    "URG-04LX-like: 3 cm, 5.6 m, 240°, 683 b": (
        dict(beams=683, range_noise=0.03, range_max=5.6, fov=np.radians(240.0)), 0.0),
    "5 cm, 20 m, 360 b": (dict(range_noise=0.05), 0.0),
    "low-cost: 2 cm + 1 % of range, 12 m, 720 b, dropouts, mixed pixels": (
        dict(beams=720, range_noise=0.02, range_max=12.0, range_noise_per_m=0.01, dropout=0.1,
             mixed_pixels=0.3), 0.5),
}


def judged(world, laser, seed):
    """The growth (1/m) RefinedScanMatcher would judge from the first 30 scans of a route."""
    from sclam_ros.core import se2
    from sclam_ros.core.inputs import Scan
    from sclam_ros.frontend import point_to_line
    from sclam_ros.sim.motion import TrueKinematics
    from sclam_ros.sim.sensors import LaserModel
    from sclam_ros.sim.trajectory import simulate_trajectory

    route = simulate_trajectory(world, TrueKinematics(0.1, 0.1, 0.5), 30.0, seed, robot_radius=0.3)
    rng = np.random.default_rng(seed)
    model = LaserModel(**laser)
    angles = model.angles()
    noises, samples = [], []
    for pose in se2.compose(route.pose_at(0.3 * np.arange(point_to_line.NOISE_SCANS)), MOUNT):
        ranges = model.measure(world.raycast(pose, angles, model.range_max)[None], rng)[0]
        scan = Scan(0.0, ranges, model.angle_min, model.angle_increment, model.range_min,
                    model.range_max)
        noise = point_to_line.range_noise(scan)
        if noise is not None:
            noises.append(noise)
        median = float(np.median(noises)) if noises else None
        if median is not None and point_to_line.NOISY_RANGE <= median <= point_to_line.NOT_A_NOISE:
            samples.append(point_to_line.range_errors(scan, median))
    return point_to_line.judged_growth(samples)


def main():
    from sclam_ros.sim.world import scene_world

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--drives", type=int, default=40, help="routes per scene and laser")
    args = ap.parse_args()
    rows = []
    for scene in ("office", "corridors", "outdoor"):
        world = scene_world(scene)
        for name, (laser, truth) in LASERS.items():
            growth = np.array([judged(world, laser, seed) for seed in range(1, args.drives + 1)])
            used = growth[growth > 0]
            rows.append([scene, name, f"{truth:.2f}", f"{len(used)} of {len(growth)}",
                         f"{np.min(used):.2f} … {np.max(used):.2f}" if len(used) else "–",
                         f"{np.median(used):.2f}" if len(used) else "–"])
            print(f"{scene} {name}: done", file=sys.stderr, flush=True)
    print(f"{args.drives} routes per scene, the first {30} scans 0.3 s apart")
    print(table(rows, ["scene", "laser", "simulated growth /m", "judged growing",
                       "judged growth /m, range", "median"]))


if __name__ == "__main__":
    main()
