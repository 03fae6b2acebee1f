"""The shape of the graph's edge errors at the simulator's truth, against the stated model.

The reported σ is right if each edge type's errors have the covariance the graph states
for them, times the one variance scale per edge type that the calibration estimates from
its residuals (variance_components.solve_with_variance_components), with the lag-1
correlation of consecutive scan matches that the chain-correlated model adds. Here each edge's error is
taken at the truth (the simulator's poses and calibration), whitened by the stated model
and divided by that scale, per component (x, y, θ of the edge):

  - mean square: 1 where the stated shape is right; a component below 1 is noisier in the
    model than in the data (its σ overstates what rests on it);
  - lag-1 correlation between consecutive edges (the scan matches share a scan);
  - RMS err/σ per parameter of the chain-correlated covariance with one noise scale per
    edge type, with the odometry's scale per component from the residuals (as the
    calibration computes it, variance_components.component_scales), and with what only the
    simulator knows put in their place: the odometry's variance per component at the truth's mean
    square, then also the scan matches' variance and lag-1 correlation per component.
    Where these move RMS err/σ toward 1, the stated shape is what makes the σ
    conservative, not the estimate of one scale or one correlation.

Run: .venv/bin/python bench/error_structure.py [--rows 0 9] [--seeds 12] [--duration 120]
"""
from __future__ import annotations

import argparse
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import scratch_dir, table  # noqa: E402
from sensor_matrix import ROWS  # noqa: E402

FACTORS = ("odometry", "laser")


def whitened_at_truth(result, bag, truth, name) -> np.ndarray:
    """(m, d) errors of the factor `name` at the true poses and calibration, whitened by the
    stated model and divided by the square root of the factor's variance scale."""
    from sclam_ros.core.params import CALIBRATION_KEYS
    from sclam_ros.io.recording import read_ground_truth

    problem = result.problem
    stamps, poses = read_ground_truth(bag)
    values = problem.values.copy()
    values["poses"] = np.column_stack([np.interp(result.stamps, stamps, poses[:, 0]),
                                       np.interp(result.stamps, stamps, poses[:, 1]),
                                       np.interp(result.stamps, stamps, np.unwrap(poses[:, 2]))])
    values["odometry"] = np.array([[truth[k] for k in CALIBRATION_KEYS[:3]]])
    values["laser"] = np.array([[truth[k] for k in CALIBRATION_KEYS[3:]]])
    factor = next(f for f in problem.factors if f.name == name)
    lin = factor.linearize(values)
    whitened = np.einsum("mij,mj->mi", lin.sqrt_information, lin.residual)
    return whitened / np.sqrt(result.variance_scales.get(name, 1.0)), factor


def run_one(job):
    row_name, seed, duration, workdir = job
    from sclam_ros.core.correlated_covariance import chain_correlated_covariance, chained_edges
    from sclam_ros.core.covariance import Influence
    from sclam_ros.core.estimator import calibrate_keyframes
    from sclam_ros.core.params import CALIBRATION_KEYS, SclamParams
    from sclam_ros.io.recording import read_recording
    from sclam_ros.sim import simulate

    bag = Path(workdir) / f"row{list(ROWS).index(row_name)}_seed{seed}"
    truth = simulate(bag, duration=duration, seed=seed, overwrite=True, **ROWS[row_name])
    params = SclamParams.from_yaml(bag / "params.yaml")
    recording = read_recording(bag, params)
    result = calibrate_keyframes(recording.keyframes, params, recording.rejections)
    out = dict(row=row_name)
    for name in FACTORS:
        whitened, factor = whitened_at_truth(result, bag, truth, name)
        t, u = chained_edges(factor)
        square = np.mean(whitened**2, axis=0)
        out[f"{name} square"] = square
        out[f"{name} lag-1"] = np.mean(whitened[t] * whitened[u], axis=0) / square
    error = np.array([result.estimate[k] - truth[k] for k in CALIBRATION_KEYS])
    problem, blocks = result.problem, ["odometry", "laser"]
    influence = Influence.of(problem, problem.values, blocks)
    one_scale, residual_rho = chain_correlated_covariance(
        problem, problem.values, blocks, influence=influence, per_component=False)
    chain, _ = chain_correlated_covariance(problem, problem.values, blocks, influence=influence)
    # H⁻¹ Jᵀ C J H⁻¹ with C's blocks changed from the model's (identity, and the residuals'
    # ρ between chained matches) to the truth's: rows are J H⁻¹ E per whitened row.
    rows = {name: influence.rows[start:stop].reshape(-1, 3, len(error))
            for name, start, stop in influence.system.row_ranges if name in FACTORS}
    odometry = np.einsum("tip,i,tiq->pq", rows["odometry"], out["odometry square"] - 1.0, rows["odometry"])
    laser_factor = next(f for f in problem.factors if f.name == "laser")
    t, u = chained_edges(laser_factor)
    true_rho = np.clip(out["laser lag-1"], -0.5, 0.0)
    las = rows["laser"]
    laser = (np.einsum("tip,i,tiq->pq", las, out["laser square"] - 1.0, las)
             + _chained(las, t, u, out["laser square"] * true_rho) - _chained(las, t, u, residual_rho["laser"]))
    out["z chain-correlated, one noise scale per edge type"] = error / np.sqrt(np.diag(one_scale))
    out["z the same, the odometry's per component (as calibrated)"] = error / np.sqrt(np.diag(chain))
    out["z the odometry's at the truth's per component"] = error / np.sqrt(np.diag(one_scale + odometry))
    out["z and the matches' variance and correlation at the truth's"] = error / np.sqrt(
        np.diag(one_scale + odometry + laser))
    out["z reported"] = error / np.array([result.sigma[k] for k in CALIBRATION_KEYS])
    return out


def _chained(rows, t, u, covariance):
    """Σ over chained pairs of rowsᵀ diag(covariance) rows, both ways round."""
    cross = np.einsum("tip,i,tiq->pq", rows[t], covariance, rows[u])
    return cross + cross.T


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--rows", nargs="+", type=int, default=[0, 9], help="rows of bench/sensor_matrix.py")
    ap.add_argument("--seeds", type=int, default=12)
    ap.add_argument("--duration", type=float, default=120.0)
    ap.add_argument("--jobs", type=int, default=2)
    args = ap.parse_args()
    names = [list(ROWS)[r] for r in args.rows]
    workdir = scratch_dir("error_structure")
    jobs = [(n, s, args.duration, str(workdir)) for n in names for s in range(1, args.seeds + 1)]
    with ProcessPoolExecutor(args.jobs) as pool:
        results = list(pool.map(run_one, jobs))
    print(f"PowerBot, {args.seeds} seeds × {args.duration:.0f} s per row; edge errors at the "
          "simulator's truth, whitened by the stated model and the edge type's variance scale "
          "(x y θ of the edge; mean over seeds)")
    keys = [f"{n} {q}" for n in FACTORS for q in ("square", "lag-1")]
    print(table([[name] + [" ".join(f"{v:+.2f}" if "lag" in k else f"{v:.2f}"
                                    for v in np.mean([r[k] for r in results if r["row"] == name], axis=0))
                           for k in keys] for name in names],
                ["laser / scene"] + [f"{k}, x y θ" for k in keys]))
    print()
    print("RMS err/σ r_l r_r b x y yaw")
    zkeys = [k for k in results[0] if k.startswith("z ")]
    print(table([[name] + [" ".join(f"{v:.2f}" for v in np.sqrt(np.mean(np.square(
        [r[k] for r in results if r["row"] == name]), axis=0))) for k in zkeys] for name in names],
        ["laser / scene"] + [k[2:] for k in zkeys]))


if __name__ == "__main__":
    main()
