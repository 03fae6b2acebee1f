"""Figures a person looks at instead of reading numbers: trajectories and residuals."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from sclam_ros.core import kinematics, se2
from sclam_ros.core.graph import GraphInputs


def integrate_odometry(inputs: GraphInputs, k) -> np.ndarray:
    """Dead reckoning through the keyframes with wheel parameters k (gaps: stay put)."""
    motion = np.zeros((inputs.size, 3))
    motion[inputs.odo_from + 1] = kinematics.forward(inputs.odo_dphi, k)
    return se2.chain(motion)


def ground_truth_at(bag_path, stamps):
    """The recording's ground truth at `stamps` in the frame of the first, or None."""
    from sclam_ros.io.recording import read_ground_truth

    gt = read_ground_truth(bag_path)
    if gt is None:
        return None
    t, poses = gt
    theta = np.unwrap(poses[:, 2])
    at = np.column_stack([np.interp(stamps, t, poses[:, 0]), np.interp(stamps, t, poses[:, 1]),
                          np.interp(stamps, t, theta)])
    # Express in the frame of the first keyframe, like the estimated trajectories.
    return se2.between(at, at[0])


def write_calibration_report(out_dir, bag_path, result, params) -> list:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    inputs = result.inputs
    nominal_k = np.array([result.nominal[k] for k in ("wheel_radius_left", "wheel_radius_right", "wheel_base")])
    est_k = np.array([result.estimate[k] for k in ("wheel_radius_left", "wheel_radius_right", "wheel_base")])
    figures = []

    fig, ax = plt.subplots(figsize=(8, 7))
    truth = ground_truth_at(bag_path, inputs.stamps)
    if truth is not None:
        ax.plot(truth[:, 0], truth[:, 1], "k-", lw=2.5, alpha=0.35, label="ground truth")
    nominal = integrate_odometry(inputs, nominal_k)
    calibrated = integrate_odometry(inputs, est_k)
    ax.plot(nominal[:, 0], nominal[:, 1], "r-", lw=1, label="odometry, nominal parameters")
    ax.plot(calibrated[:, 0], calibrated[:, 1], "b-", lw=1, label="odometry, calibrated parameters")
    ax.plot(result.poses[:, 0], result.poses[:, 1], "g--", lw=1, label="optimised graph")
    ax.set_aspect("equal")
    ax.set_xlabel("x [m] (frame of the first scan)")
    ax.set_ylabel("y [m]")
    ax.set_title("Trajectories")
    ax.legend(loc="best", fontsize=8)
    path = out / "trajectories.png"
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)
    figures.append(path)

    problem = result.problem
    values = problem.values
    fig, axes = plt.subplots(3, 2, figsize=(11, 8), sharex="col")
    labels = ("x [mm]", "y [mm]", "θ [deg]")
    scales = (1000.0, 1000.0, np.degrees(1.0))
    for col, factor in enumerate(f for f in problem.factors if f.name in ("odometry", "laser")):
        residual = factor.residuals(values)
        stamps = inputs.stamps[factor.pose_j]
        for row in range(3):
            ax = axes[row, col]
            ax.plot(stamps - inputs.stamps[0], residual[:, row] * scales[row], ".", ms=1.5)
            ax.axhline(0, color="k", lw=0.5)
            ax.set_ylabel(labels[row])
            if row == 0:
                rms = np.sqrt(np.mean(residual**2, axis=0))
                ax.set_title(f"{factor.name} residuals (RMS {rms[0]*1000:.2f} mm, "
                             f"{rms[1]*1000:.2f} mm, {np.degrees(rms[2]):.3f}°)", fontsize=9)
        axes[2, col].set_xlabel("time since first scan [s]")
    path = out / "residuals.png"
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    figures.append(path)
    return figures
