"""The wheel odometry's sideways error per scan match against the simulator's ground
truth: one arc over the match against arcs cut at the encoder samples in between
(SyncConfig.min_arc), and how each correlates with the change of turn rate over the
match (docs/diagnose.md, "What the second held-out set left").

Default: the second held-out set's condition "powerbot, 50 Hz 1970 ticks, 360° at 15 Hz,
corridors, jitter 2 ms" (bench/diagnose_conditions.py HELD_OUT_2), seed 201, 120 s. The
wheels use the true calibration, so what is left is the model's and the slip noise's.

Run: .venv/bin/python bench/odometry_arcs.py [--seeds 201,204,209] [--condition N]
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import scratch_dir, table  # noqa: E402
from diagnose_conditions import HELD_OUT_2, simulate_options  # noqa: E402

from sclam_ros.core import kinematics, se2  # noqa: E402
from sclam_ros.core.params import SclamParams  # noqa: E402
from sclam_ros.io.recording import read_ground_truth, read_recording  # noqa: E402
from sclam_ros.io.relations import interpolate_poses  # noqa: E402
from sclam_ros.sim import simulate  # noqa: E402

TURN_RATE_STEP = 0.02  # s, each side of a stamp: the true turn rate by central difference


def match_errors(bag: Path) -> dict:
    """Per chained scan match: the true change of turn rate, and the sideways error (m) of
    the wheels' motion with one arc and with the arcs between encoder samples."""
    truth = json.loads((bag / "truth.json").read_text())
    k = np.array([truth["wheel_radius_left"], truth["wheel_radius_right"], truth["wheel_base"]])
    stamps, poses = read_ground_truth(bag)
    params = SclamParams.from_yaml(bag / "params.yaml")
    keyframes = read_recording(bag, params).keyframes
    pairs = [(keyframes[kf.laser_from], kf) for kf in keyframes
             if kf.dphi is not None and kf.laser_from == kf.index - 1]
    a = np.array([p[0].stamp for p in pairs])
    b = np.array([p[1].stamp for p in pairs])

    def turn_rate(t):
        after = interpolate_poses(stamps, poses, t + TURN_RATE_STEP)[:, 2]
        before = interpolate_poses(stamps, poses, t - TURN_RATE_STEP)[:, 2]
        return se2.wrap_angle(after - before) / (2 * TURN_RATE_STEP)

    true_motion = se2.between(interpolate_poses(stamps, poses, b), interpolate_poses(stamps, poses, a))
    one = kinematics.forward(np.array([kf.dphi for _, kf in pairs]), k)
    cut = np.array([kinematics.forward_composed(kf.dphi_parts, k)[0] if kf.dphi_parts is not None
                    else kinematics.forward(kf.dphi, k) for _, kf in pairs])
    return {"turn_rate_change": turn_rate(b) - turn_rate(a),
            "one arc": se2.between(one, true_motion)[:, 1],
            "arcs between samples": se2.between(cut, true_motion)[:, 1]}


def main(argv) -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", default="201", help="comma-separated simulator seeds")
    ap.add_argument("--condition", type=int, default=4, help="index into HELD_OUT_2")
    ap.add_argument("--duration", type=float, default=120.0)
    args = ap.parse_args(argv[1:])
    name = list(HELD_OUT_2)[args.condition]
    work = scratch_dir("odometry_arcs_")
    rows = []
    for seed in (int(s) for s in args.seeds.split(",")):
        bag = work / f"seed_{seed}"
        simulate(bag, duration=args.duration, seed=seed, overwrite=True,
                 **simulate_options(HELD_OUT_2[name]))
        errors = match_errors(bag)
        for label in ("one arc", "arcs between samples"):
            e = errors[label]
            rows.append([seed, label, len(e), f"{1e3 * np.sqrt(np.mean(e ** 2)):.3f}",
                         f"{np.corrcoef(errors['turn_rate_change'], e)[0, 1]:+.2f}"])
    print(f"{name}, {args.duration:.0f} s; wheels with the true calibration against the ground truth")
    print(table(rows, ["seed", "wheel odometry", "matches", "sideways error RMS mm",
                       "correlation with the change of turn rate"]))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
