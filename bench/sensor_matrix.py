"""Calibration accuracy on the lasers people own, indoors and outdoors, against ground truth.

Each row is a laser (rate, field of view, beams, range, noise, dropouts, mixed pixels), a
scene (the office, open ground with trees, poles and cars, or a ring of bare corridors) and
an odometry rate; each is simulated with --seeds seeds (PowerBot, --duration s, the default
drive) and calibrated as `sclam calibrate` does. Per row:

  - error per parameter: the mean over seeds (bias) and the RMS, in % of the true value for
    the radii and the base, mm and degrees for the laser; for the radii and the base also
    the mean's standard error (how far the seeds' luck can move it from the bias);
  - RMS error/σ per parameter (1 when the reported σ is honest; the acceptance band is
    0.7-1.4);
  - scale of the scan matches: Σ z·z_true / Σ |z_true|² over every laser edge of the graph
    (translation), z_true from the simulator's ground truth and the true mount: 1.0000 when
    matched displacements are neither short nor long (± its standard error over seeds);
    weighted as the graph weighs the matches, 1 + Σ w·e·L / Σ w·L² (e each match's error
    along its true motion, L the motion's length, w the match's information along it;
    matches under 2 cm left out), the scale the wheel radii follow: a match whose walls do
    not fix its motion along a corridor weighs little there;
    and their turn, Σ z_true × z / Σ |z_true|² in degrees (0 when matched translations
    point where the true ones do; a turn shows up as a laser yaw error);
  - calibration cost per second of recording (reading, matching, solving; one process per
    core, --jobs processes at once).
A second table gives the RMS err/σ with the σ of each covariance the reported one is made
of: H⁻¹, the chain-correlated model, the sandwich (estimator.calibrate_keyframes).

Run: .venv/bin/python bench/sensor_matrix.py [--seeds 10] [--duration 120] [--jobs 2] [--rows ...]
     [--first-seed 1: seeds first-seed .. first-seed + seeds - 1, to add seeds to a row]
     [--save results.json: every seed's numbers]
     [--factors urg|low-cost: that row with one factor at a time set back to the default's]
     [--true-nominal: the true calibration as the nominal one, so the odometry guess the
      scan matcher starts from is right; a bias that remains is not the guess's]
     [--outdoor-variant "without the trunks"|...: the outdoor scene's objects changed one
      factor at a time (OUTDOOR_VARIANTS)]
     [--mirrored: the scene and the robot reflected left for right (its wheel radii
      swapped, its laser's y and yaw negated): a bias that belongs to the drive's geometry
      changes sign, one that belongs to the processing does not]
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import scratch_dir, table  # noqa: E402
from sclam_ros.sim.world import OutdoorScene  # noqa: E402

DEG = math.pi / 180.0
# name: simulate() keywords. The first row is the laser the noise model was measured on.
ROWS = {
    "10 Hz, 360°, 360 b, 20 m, 1 cm (default)": {},
    "40 Hz, 270°, 1081 b, 30 m, 1 cm (UST-10LX)": dict(
        scan_rate=40.0, beams=1081, laser=dict(fov=270 * DEG, range_max=30.0)),
    "10 Hz, 240°, 683 b, 5.6 m, 3 cm (URG-04LX)": dict(
        beams=683, range_noise=0.03, laser=dict(fov=240 * DEG, range_max=5.6)),
    "10 Hz, 360°, 360 b, 20 m, 5 cm": dict(range_noise=0.05),
    "5 Hz, 360°, 720 b, 12 m, 2 cm + 1 %, 10 % dropouts, mixed pixels (low-cost)": dict(
        scan_rate=5.0, beams=720, range_noise=0.02,
        laser=dict(range_max=12.0, range_noise_per_m=0.01, dropout=0.1, mixed_pixels=0.3)),
    "25 Hz, 180°, 361 b, 20 m, 1 cm (LMS-type)": dict(
        scan_rate=25.0, beams=361, laser=dict(fov=180 * DEG)),
    "default laser, odometry 2 Hz": dict(encoder_rate=2.0),
    "default laser, odometry 1 Hz": dict(encoder_rate=1.0),
    "outdoor, default laser": dict(scene="outdoor"),
}
# --factors: a row with one of its factors changed (the URG-04LX-like and low-cost ones set
# back to the default laser's, the outdoor one's range noise).
URG = ROWS["10 Hz, 240°, 683 b, 5.6 m, 3 cm (URG-04LX)"]
OUTDOOR = ROWS["outdoor, default laser"]
LOW_COST = ROWS["5 Hz, 360°, 720 b, 12 m, 2 cm + 1 %, 10 % dropouts, mixed pixels (low-cost)"]
# A ring of bare corridors between four lobbies (sim/world.py corridors_world): rows 9-11.
ROWS["corridors, default laser"] = dict(scene="corridors")
ROWS["corridors, URG-04LX-like"] = dict(URG, scene="corridors")
ROWS["corridors, low-cost"] = dict(LOW_COST, scene="corridors")
FACTOR_ROWS = {
    "urg": {
        "URG-04LX-like": URG,
        "  with 1 cm noise": dict(URG, range_noise=0.01),
        "  with 20 m range": dict(URG, laser=dict(URG["laser"], range_max=20.0)),
        "  with 360° (1024 b)": dict(URG, beams=1024, laser=dict(URG["laser"], fov=360 * DEG)),
    },
    "low-cost": {
        "low-cost": LOW_COST,
        "  without the 1 % of range": dict(LOW_COST, laser=dict(LOW_COST["laser"], range_noise_per_m=0.0)),
        "  without dropouts and mixed pixels": dict(
            LOW_COST, laser=dict(LOW_COST["laser"], dropout=0.0, mixed_pixels=0.0)),
        "  at 10 Hz, 360 b": dict(LOW_COST, scan_rate=10.0, beams=360),
        "  with 20 m range": dict(LOW_COST, laser=dict(LOW_COST["laser"], range_max=20.0)),
    },
    # The outdoor row's range noise (the factor its bias follows), its range and the wheels' slip.
    "outdoor": {
        "outdoor, default laser (1 cm)": OUTDOOR,
        "  without range noise": dict(OUTDOOR, range_noise=1e-4),
        "  with 0.5 cm noise": dict(OUTDOOR, range_noise=0.005),
        "  with 2 cm noise": dict(OUTDOOR, range_noise=0.02),
        "  with 60 m range": dict(OUTDOOR, laser=dict(range_max=60.0)),
        "  without wheel slip": dict(OUTDOOR, slip_noise=0.0),
        "  without wheel slip or range noise": dict(OUTDOOR, slip_noise=0.0, range_noise=1e-4),
    },
}
RADII_AND_BASE = ("wheel_radius_left", "wheel_radius_right", "wheel_base")
SHORTEST_MATCH = 0.02  # m: a shorter match's direction is not defined (along_motion)


def match_bias(bag, truth, keyframes) -> tuple:
    """Scale Σ z·z_true / Σ |z_true|², turn Σ z_true × z / Σ |z_true|² (rad, positive:
    matched translations turned counter-clockwise from the true ones) and weighted scale
    (along_motion: as the graph weighs the matches) over every scan match (before keyframes
    are merged: each match between the two scans' own stamps). A turn of the matched
    translations is an error of the laser yaw, which the calibration takes from the
    direction the laser moves in when the robot drives straight."""
    z, z_true, information, _ = matches_against_truth(bag, truth, keyframes)
    norm = (z_true[:, :2] ** 2).sum()
    scale = (z[:, :2] * z_true[:, :2]).sum() / norm
    turn = (z_true[:, 0] * z[:, 1] - z_true[:, 1] * z[:, 0]).sum() / norm
    _, error, length, weight = along_motion(z, z_true, information)
    weighted = 1.0 + np.sum(weight * error * length) / np.sum(weight * length ** 2)
    return float(scale), float(turn), float(weighted)


def along_motion(z, z_true, information) -> tuple:
    """(keep (M,) bool, e, L, w) of the matches longer than SHORTEST_MATCH: e the error along
    the true motion, L its length, w the information along it (the graph's weight of the
    match's error there). A calibration's wheel radii follow the scale 1 + Σ w·e·L / Σ w·L²."""
    length = np.hypot(z_true[:, 0], z_true[:, 1])
    keep = length > SHORTEST_MATCH
    unit = z_true[keep, :2] / length[keep, None]
    error = ((z[keep, :2] - z_true[keep, :2]) * unit).sum(1)
    weight = np.einsum("mi,mij,mj->m", unit, information[keep, :2, :2], unit)
    return keep, error, length[keep], weight


def matches_against_truth(bag, truth, keyframes) -> tuple:
    """(z (M, 3), z_true (M, 3), information (M, 3, 3), true laser pose at the match's first
    scan in the odometry frame (M, 3)) of every scan match of `keyframes` (before they are
    merged), z_true from the recording's ground truth and the true mount."""
    from sclam_ros.core import se2
    from sclam_ros.io.recording import read_ground_truth

    stamps, poses = read_ground_truth(bag)
    unwrapped = np.unwrap(poses[:, 2])
    stamp_of = {kf.index: kf.stamp for kf in keyframes}
    matched = [kf for kf in keyframes if kf.laser_motion is not None and kf.laser_from in stamp_of]

    def laser_pose(t):
        base = np.array([np.interp(t, stamps, poses[:, 0]), np.interp(t, stamps, poses[:, 1]),
                         np.interp(t, stamps, unwrapped)]).T
        return se2.compose(base, np.array([truth["laser_x"], truth["laser_y"], truth["laser_yaw"]]))

    a = laser_pose(np.array([stamp_of[kf.laser_from] for kf in matched]))
    b = laser_pose(np.array([kf.stamp for kf in matched]))
    return (np.array([kf.laser_motion for kf in matched]), se2.between(b, a),
            np.array([kf.laser_information for kf in matched]), a)


def run_one(job):
    """Simulate and calibrate one row/seed; the numbers the table needs (or the failure)."""
    number, name, row, seed, duration, workdir, true_nominal = job
    from sclam_ros.core.estimator import CalibrationError, calibrate_keyframes
    from sclam_ros.core.params import CALIBRATION_KEYS, SclamParams
    from sclam_ros.io.recording import read_recording
    from sclam_ros.sim import simulate

    bag = Path(workdir) / f"row{number}_seed{seed}"
    truth = simulate(bag, duration=duration, seed=seed, overwrite=True, **row)
    params = SclamParams.from_yaml(bag / "params.yaml")
    if true_nominal:
        params = dataclasses.replace(params, **{k: truth[k] for k in CALIBRATION_KEYS})
    start = time.perf_counter()
    try:
        recording = read_recording(bag, params)
        result = calibrate_keyframes(recording.keyframes, params, recording.rejections)
    except CalibrationError as exc:
        return dict(name=name, seed=seed, failed=str(exc).splitlines()[0])
    cost = (time.perf_counter() - start) / duration
    error = {k: result.estimate[k] - truth[k] for k in CALIBRATION_KEYS}
    scale, turn, weighted_scale = match_bias(bag, truth, recording.keyframes)
    err = np.array([error[k] for k in CALIBRATION_KEYS])
    return dict(
        name=name, seed=seed, failed=None, cost=cost, scale=scale, turn=turn,
        weighted_scale=weighted_scale,
        error=error, z={k: error[k] / result.sigma[k] for k in CALIBRATION_KEYS},
        z_by_source={source: (err / sigma).tolist() for source, sigma in sigma_sources(result).items()},
        relative={k: 100.0 * error[k] / truth[k] for k in RADII_AND_BASE},
        observable=all(result.observable.values()),
    )


def sigma_sources(result) -> dict:
    """The σ of each covariance the reported one is made of (estimator.calibrate_keyframes):
    H⁻¹ (every edge independent), the chain-correlated model (consecutive scan matches'
    residual correlation), the sandwich (the residuals' own spread); and the reported σ."""
    from sclam_ros.core.correlated_covariance import (
        chain_correlated_covariance,
        sandwich_covariance,
    )
    from sclam_ros.core.covariance import Influence

    problem, blocks = result.problem, ["odometry", "laser"]
    influence = Influence.of(problem, problem.values, blocks)
    covariances = {
        "H⁻¹": influence.marginal,
        "chain-correlated": chain_correlated_covariance(problem, problem.values, blocks,
                                                        influence=influence)[0],
        "sandwich": sandwich_covariance(problem, problem.values, blocks, influence=influence),
        "reported": result.covariance,
    }
    return {k: np.sqrt(np.diag(c)) for k, c in covariances.items()}


def sigma_source_cells(name, results):
    ok = [r for r in results if not r["failed"]]
    if not ok:
        return [name] + ["-"] * 4
    return [name] + [" ".join(f"{v:.2f}" for v in np.sqrt(np.mean(np.square(
        [r["z_by_source"][source] for r in ok]), axis=0))) for source in ok[0]["z_by_source"]]


def row_cells(name, results):
    from sclam_ros.core.params import CALIBRATION_KEYS

    ok = [r for r in results if not r["failed"]]
    failed = len(results) - len(ok)
    if not ok:
        return [name, f"0/{len(results)}"] + ["-"] * 10
    rel = np.array([[r["relative"][k] for k in RADII_AND_BASE] for r in ok])
    laser = np.array([[1e3 * r["error"]["laser_x"], 1e3 * r["error"]["laser_y"],
                       math.degrees(r["error"]["laser_yaw"])] for r in ok])
    z = np.array([[r["z"][k] for k in CALIBRATION_KEYS] for r in ok])
    rms_z = np.sqrt(np.mean(z ** 2, axis=0))
    scales = np.array([r["scale"] for r in ok])
    weighted_scales = np.array([r["weighted_scale"] for r in ok])
    turns = np.degrees([r["turn"] for r in ok])
    return [
        name, f"{len(ok)}/{len(results)}",
        " ".join(f"{m:+.3f}" for m in rel.mean(0)),
        " ".join(f"{v:.3f}" for v in _standard_error(rel)),
        " ".join(f"{v:.3f}" for v in np.sqrt(np.mean(rel ** 2, axis=0))),
        " ".join(f"{v:+.2f}" for v in laser[:, :2].mean(0)) + f" / {laser[:, 2].mean():+.3f}",
        " ".join(f"{v:.2f}" for v in np.sqrt(np.mean(laser[:, :2] ** 2, axis=0)))
        + f" / {np.sqrt(np.mean(laser[:, 2] ** 2)):.3f}",
        " ".join(f"{v:.2f}" for v in rms_z),
        f"{scales.mean():.4f} ± {_standard_error(scales[:, None])[0]:.4f}",
        f"{weighted_scales.mean():.4f} ± {_standard_error(weighted_scales[:, None])[0]:.4f}",
        f"{turns.mean():+.3f} ± {_standard_error(turns[:, None])[0]:.3f}",
        f"{1e3 * np.median([r['cost'] for r in ok]):.0f}",
    ]


def _standard_error(samples):
    """Standard error of the mean of each column of (seeds, k) samples: how far a row's mean
    error may be from its bias by the luck of its seeds (0 with one seed)."""
    samples = np.asarray(samples, float)
    if len(samples) < 2:
        return np.zeros(samples.shape[1])
    return samples.std(axis=0, ddof=1) / math.sqrt(len(samples))


# The outdoor scene's objects changed one factor at a time (sim/world.py OutdoorScene): the
# trunks rounder (32-gons), as square boxes of the same width, or gone, or the parked cars
# gone (the poles and the façade stay).
OUTDOOR_VARIANTS = {
    "as simulated (trunks as octagons)": OutdoorScene(),
    "trunks as 32-gons": OutdoorScene(trunks="32-gon"),
    "trunks as square boxes": OutdoorScene(trunks="box"),
    "without the trunks": OutdoorScene(trunks="none"),
    "without the parked cars": OutdoorScene(parked_cars=False),
}


def mirrored_row(row) -> dict:
    """`row` (simulate keywords) with its scene and its robot mirrored left for right."""
    from sclam_ros.sim.robots import get_preset
    from sclam_ros.sim.world import MIRRORED

    true = get_preset(row.get("robot", "powerbot")).true
    return dict(row, scene=row.get("scene", "office") + MIRRORED, true_overrides=dict(
        wheel_radius_left=true["wheel_radius_right"], wheel_radius_right=true["wheel_radius_left"],
        laser_y=-true["laser_y"], laser_yaw=-true["laser_yaw"]))


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--first-seed", type=int, default=1)
    ap.add_argument("--duration", type=float, default=120.0)
    ap.add_argument("--jobs", type=int, default=2, help="processes at once (one per core)")
    ap.add_argument("--rows", nargs="+", type=int, default=None,
                    help="row numbers to run (0-based, in the order listed in ROWS)")
    ap.add_argument("--factors", choices=sorted(FACTOR_ROWS),
                    help="instead of the sensors, that row one factor at a time")
    ap.add_argument("--true-nominal", action="store_true",
                    help="start from the true calibration (the scan matcher's guess is right)")
    ap.add_argument("--save", type=Path, help="also write every seed's numbers to this JSON file")
    ap.add_argument("--mirrored", action="store_true",
                    help="the scene and the robot reflected left for right (see above)")
    ap.add_argument("--outdoor-variant", choices=OUTDOOR_VARIANTS,
                    help="the outdoor scene with its trunks reshaped or removed "
                         "(OUTDOOR_VARIANTS); other scenes are unchanged")
    args = ap.parse_args()
    if args.factors:
        ROWS.clear()
        ROWS.update(FACTOR_ROWS[args.factors])
    names = [n for i, n in enumerate(ROWS) if args.rows is None or i in args.rows]
    if args.outdoor_variant:
        ROWS.update({n: dict(ROWS[n], outdoor=OUTDOOR_VARIANTS[args.outdoor_variant]) for n in names})
    if args.mirrored:
        ROWS.update({n: mirrored_row(ROWS[n]) for n in names})
    workdir = scratch_dir("sclam_sensor_matrix_")
    jobs = [(number, name, ROWS[name], seed, args.duration, workdir, args.true_nominal)
            for number, name in enumerate(names) for seed in range(args.first_seed, args.first_seed + args.seeds)]
    with ProcessPoolExecutor(args.jobs) as pool:
        results = list(pool.map(run_one, jobs))
    if args.save:
        args.save.write_text(json.dumps(results, indent=1))
    for r in results:
        if r["failed"]:
            print(f"{r['name']} seed {r['seed']}: no calibration: {r['failed']}", file=sys.stderr)
    print(f"PowerBot, {args.seeds} seeds ({args.first_seed}–{args.first_seed + args.seeds - 1}) × "
          f"{args.duration:.0f} s per row; errors against the "
          f"simulator's truth" + ("; the true calibration as nominal" if args.true_nominal else "")
          + (f"; outdoor scene {args.outdoor_variant}" if args.outdoor_variant else "")
          + ("; the scene and the robot mirrored" if args.mirrored else ""))
    print(table([row_cells(n, [r for r in results if r["name"] == n]) for n in names],
                ["laser / scene", "calibrated", "mean error r_l r_r b %", "its standard error %",
                 "RMS error r_l r_r b %", "mean laser error x y mm / yaw °",
                 "RMS laser x y mm / yaw °", "RMS err/σ r_l r_r b x y yaw", "match scale",
                 "match scale, weighted",
                 "match turn °", "ms per s recorded"]))
    print("\nRMS err/σ r_l r_r b x y yaw with the σ of each covariance the reported one is made "
          "of (the reported: the chain-correlated, raised per parameter to the sandwich's)")
    print(table([sigma_source_cells(n, [r for r in results if r["name"] == n]) for n in names],
                ["laser / scene", "H⁻¹", "chain-correlated", "sandwich", "reported"]))


if __name__ == "__main__":
    main()
