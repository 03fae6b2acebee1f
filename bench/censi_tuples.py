"""Calibrate Censi et al.'s Khepera III tuples with our graph and compare to the paper.

    .venv/bin/python bench/censi_tuples.py [DATA_DIR]

DATA_DIR defaults to ../shared/data/censi-khepera-tuples beside the repository (read in
place; the data has no licence and is never copied). Prints, per laser mounting, our
estimate ± marginal σ beside the published one ± its σ (radii = diameters / 2), the
distance in published σ, the down-weighted scan matches and the wall time.
"""
import sys
import time
from pathlib import Path

import numpy as np

from sclam_ros.io import censi

NAMES = ("r_l [mm]", "r_r [mm]", "b [mm]", "l_x [mm]", "l_y [mm]", "l_yaw [deg]")
SCALE = np.array([1e3, 1e3, 1e3, 1e3, 1e3, 180 / np.pi])


def main(argv):
    data = Path(argv[1]) if len(argv) > 1 else (
        Path(__file__).resolve().parents[2] / "shared" / "data" / "censi-khepera-tuples")
    if not data.is_dir():
        print(f"{data} not found", file=sys.stderr)
        return 1
    worst = 0.0
    for mounting in censi.MOUNTINGS:
        tuples = censi.load_tuples(data / f"{mounting}.tuple")
        published, cov = censi.load_published(data / f"{mounting}_results.json")
        start = time.perf_counter()
        ours = censi.calibrate_tuples(tuples)
        seconds = time.perf_counter() - start
        z = censi.compare(ours, published, cov)
        worst = max(worst, float(z.max()))
        print(f"\n{mounting}: {len(tuples)} tuples, {ours.downweighted} scan matches "
              f"down-weighted (robust weight < {censi.DOWNWEIGHT_WEIGHT}), "
              f"start yaw {np.degrees(ours.nominal[5]):.1f} deg, {seconds:.1f} s, "
              f"variance scales {', '.join(f'{k} {v:.3g}' for k, v in ours.variance_scales.items())}")
        print(f"  {'parameter':<12} {'ours ± σ':>22} {'Censi 2013 ± σ':>22} {'|Δ|/σ_pub':>10}")
        for i, name in enumerate(NAMES):
            s = SCALE[i]
            print(f"  {name:<12} {ours.estimate[i] * s:>12.3f} ± {ours.sigma[i] * s:<7.3f}"
                  f" {published[i] * s:>12.3f} ± {np.sqrt(cov[i, i]) * s:<7.3f} {z[i]:>10.2f}")
    print(f"\nworst |Δ| = {worst:.2f} published σ")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
