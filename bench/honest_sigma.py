"""Acceptance 3 of the calibration issue: is the reported σ honest?

Over N seeds, each parameter's error divided by its reported σ should have an RMS near 1
(target: between 0.5 and 2).

Run: .venv/bin/python bench/honest_sigma.py [--seeds 20] [--duration 120] [--robot powerbot]
"""
import argparse

import numpy as np
from common import errors, simulate_and_calibrate, table

from sclam_ros.core.params import CALIBRATION_KEYS


def main():
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--duration", type=float, default=120.0)
    ap.add_argument("--robot", default="powerbot")
    args = ap.parse_args()
    z, z_model = [], []
    for seed in range(args.seeds):
        truth, result, _, _ = simulate_and_calibrate(args.robot, args.duration, 100 + seed)
        e = errors(truth, result)
        z.append([e[k] / result.sigma[k] for k in CALIBRATION_KEYS])
        model_sigma = np.sqrt(np.diag(result.model_covariance))
        z_model.append([e[k] / s for k, s in zip(CALIBRATION_KEYS, model_sigma)])
        print(f"seed {100 + seed}: err/σ " + " ".join(f"{v:+.2f}" for v in z[-1]), flush=True)
    z, z_model = np.array(z), np.array(z_model)
    rms = np.sqrt(np.mean(z**2, axis=0))
    rms_model = np.sqrt(np.mean(z_model**2, axis=0))
    rows = [[k, f"{np.mean(z[:, i]):+.2f}", f"{rms[i]:.2f}", "yes" if 0.5 <= rms[i] <= 2 else "NO",
             f"{rms_model[i]:.2f}"]
            for i, k in enumerate(CALIBRATION_KEYS)]
    print(f"\n{args.robot}, {args.seeds} seeds × {args.duration:.0f} s (σ = reported σ: the noise "
          f"model's with consecutive scan matches' correlation, raised where the residual spread "
          f"is larger; last column: H⁻¹ alone, every edge independent):")
    print(table(rows, ["parameter", "mean err/σ", "RMS err/σ", "0.5 ≤ RMS ≤ 2", "RMS err/σ_model"]))


if __name__ == "__main__":
    main()
