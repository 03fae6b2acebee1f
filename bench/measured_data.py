"""Calibration and residual diagnosis on the measured data sets (docs/measured_data.md).

    .venv/bin/python bench/measured_data.py [DATA_DIR] [--out DIR] [--skip-mines] [--skip-optiodom]

DATA_DIR defaults to ../shared/data beside the repository; a data set that is absent is
skipped with a message (exit 0). Prints the tables quoted in docs/measured_data.md and
writes the figures to docs/figures/ (or --out).

breezyslam-mines exp1/exp2: convert, base calibration + `sclam diagnose` (library
effects, 5-fold time-block held-out NLL), and the direct check of the clock offset the
diagnosis finds: the encoder columns shifted by whole log lines, recalibrated.
optiodom-diff: per run, the mocap calibration (sclam_ros.mocap) with and without the
library's time_offset in the graph; cross-run prediction: k fitted on one run, the
odometry-vs-mocap residual RMS of every other run (marker mount refitted there, k fixed).
"""
import sys
import tempfile
from pathlib import Path

import numpy as np

from sclam_ros import graph as graph_mod
from sclam_ros import kinematics, se2
from sclam_ros.convert import (convert_breezyslam, optiodom_params, read_optiodom)
from sclam_ros.diagnose import diagnose_keyframes, write_diagnosis_report
from sclam_ros.effects import LIBRARY, EffectData
from sclam_ros.effects.model import extend_problem
from sclam_ros.mocap import graph_inputs, initial_mount_yaw
from sclam_ros.offline import read_recording
from sclam_ros.params import CALIBRATION_KEYS, SclamParams
from sclam_ros.solver import marginal_covariance, solve_with_variance_components

ROOT = Path(__file__).resolve().parents[1]


def _shift_ticks(src, dst, lines):
    """The .dat with the tick columns (2, 3) taken `lines` log lines later (>0) or earlier."""
    rows = [line.split() for line in Path(src).read_text().splitlines() if line.strip()]
    ticks = [(r[2], r[3]) for r in rows]
    n = len(rows)
    out = []
    for i, r in enumerate(rows):
        k = i + lines
        if 0 <= k < n:
            r = list(r)
            r[2], r[3] = ticks[k]
            out.append(" ".join(r))
    Path(dst).write_text("\n".join(out) + "\n")


def mines(data: Path, figures: Path):
    runs = [data / "breezyslam-mines" / f"exp{n}.dat" for n in (1, 2)]
    if not all(p.exists() for p in runs):
        print(f"skipping breezyslam-mines: not found under {data}")
        return
    print("\n## breezyslam-mines\n")
    work = Path(tempfile.mkdtemp(prefix="mines_"))
    rows = []
    for src in runs:
        for shift in (0, -1, 1):
            name = f"{src.stem} shift {shift:+d}"
            dat = work / f"{src.stem}_{shift}.dat"
            _shift_ticks(src, dat, shift)
            convert_breezyslam(dat, work / dat.stem)
            params = SclamParams.from_yaml(work / dat.stem / "params.yaml")
            rec = read_recording(work / dat.stem / "bag", params)
            diag = diagnose_keyframes(rec.keyframes, params,
                                      effect_names=["time_offset", "lateral_slip", "radius_drift"])
            rep = diag.report
            if shift == 0:
                write_diagnosis_report(figures / f"mines_{src.stem}", diag)
            b, e = rep["base"], rep["extended"]
            off = next(x for x in rep["effects"] if x["name"] == "time_offset")
            rows.append((name, b["params"], b["error"], e["params"], e["error"],
                         [x["name"] for x in rep["effects"] if x["selected"]], off,
                         rep["unexplained"]))
    print("| run, tick shift (lines) | base r_l, r_r, b [mm] | base held-out NLL | selected "
          "| time_offset [ms] | extended r_l, r_r, b [mm] | extended NLL | unexplained |")
    print("|---|---|---|---|---|---|---|---|")
    for name, bp, be, ep, ee, sel, off, unexp in rows:
        fmt = lambda p: ", ".join(f"{p[k] * 1e3:.1f}" for k in CALIBRATION_KEYS[:3])
        u = "; ".join(f"{x['component']}~{x['regressor']} {x['strength']:.2f}" for x in unexp[:3])
        print(f"| {name} | {fmt(bp)} | {be:.3f} | {', '.join(sel) or 'none'} | "
              f"{off['value'] * 1e3:.1f} ± {off['sigma'] * 1e3:.1f} | {fmt(ep)} | {ee:.3f} | {u or '-'} |")


def _mocap_problem(stamps, ticks, truth, params, step, effects=(), k=None):
    inputs = graph_inputs(stamps, ticks, truth, params.ticks_per_revolution, step)
    k0 = np.array([params.wheel_radius_left, params.wheel_radius_right, params.wheel_base])
    kk = k0 if k is None else k
    nominal = np.concatenate([kk, [0.0, 0.0, initial_mount_yaw(inputs, kk)]])
    problem = graph_mod.build_problem(
        inputs, params.with_calibration(dict(zip(CALIBRATION_KEYS, nominal))), nominal)
    if effects:
        angles = np.asarray(ticks, float) * 2 * np.pi / params.ticks_per_revolution
        speeds = np.gradient(angles, stamps, axis=0)
        data = EffectData(inputs.stamps, np.column_stack(
            [np.interp(inputs.stamps, stamps, speeds[:, c]) for c in range(2)]))
        problem = extend_problem(problem, [LIBRARY[n](data) for n in effects])
    if k is not None:
        problem.fixed = {**problem.fixed, "odometry": np.array([0])}
        problem = type(problem)(problem.values, problem.factors, fixed=problem.fixed,
                                kernels=problem.kernels, scales=problem.scales)
    return problem


def _odometry_rms(problem, values):
    f = next(f for f in problem.factors if f.name == "odometry")
    r = f.residuals(values)
    return np.sqrt(np.mean(r[:, :2] ** 2)) * 1e3, np.degrees(np.sqrt(np.mean(r[:, 2] ** 2)))


def optiodom(data: Path, step=10):
    runs = sorted((data / "optiodom-diff").glob("*/*/*_run-??.csv"))
    if not runs:
        print(f"skipping optiodom-diff: no runs under {data}")
        return
    print("\n## optiodom-diff\n")
    params = optiodom_params()
    fits = {}
    print("| run | r_l, r_r, b [mm] | odo RMS [mm, deg] | time_offset [ms] | "
          "r_l, r_r, b with offset [mm] | odo RMS with offset |")
    print("|---|---|---|---|---|---|")
    loaded = {}
    for path in runs:
        stamps, truth, ticks = read_optiodom(path)
        name = path.parent.parent.name[:4] + path.stem[-2:]
        loaded[name] = (stamps, truth, ticks)
        p0 = _mocap_problem(stamps, ticks, truth, params, step)
        r0, _ = solve_with_variance_components(p0)
        p1 = _mocap_problem(stamps, ticks, truth, params, step, effects=["time_offset"])
        r1, _ = solve_with_variance_components(p1)
        cov = marginal_covariance(p1, r1.values, ["time_offset"])
        k0 = r0.values["odometry"][0]
        k1 = r1.values["odometry"][0]
        fits[name] = k0
        rms0, rms1 = _odometry_rms(p0, r0.values), _odometry_rms(p1, r1.values)
        print(f"| {name} | {', '.join(f'{x * 1e3:.2f}' for x in k0)} | {rms0[0]:.2f}, {rms0[1]:.3f} | "
              f"{r1.values['time_offset'][0][0] * 1e3:.1f} ± {np.sqrt(cov[0, 0]) * 1e3:.1f} | "
              f"{', '.join(f'{x * 1e3:.2f}' for x in k1)} | {rms1[0]:.2f}, {rms1[1]:.3f} |")
    ks = np.array(list(fits.values())) * 1e3
    print(f"\nrepeatability over {len(ks)} runs (mean ± sd, mm): "
          + ", ".join(f"{m:.2f} ± {s:.2f}" for m, s in zip(ks.mean(0), ks.std(0, ddof=1))))
    # Cross-run: k from run A, mount refitted on run B with k fixed, odometry RMS on B.
    names = list(fits)
    own, nominal, cross = [], [], []
    k_nom = np.array([params.wheel_radius_left, params.wheel_radius_right, params.wheel_base])
    for b in names:
        stamps, truth, ticks = loaded[b]
        for a in names:
            k = fits[a] if a != "nominal" else k_nom
            p = _mocap_problem(stamps, ticks, truth, params, step, k=k)
            r, _ = solve_with_variance_components(p)
            (own if a == b else cross).append(_odometry_rms(p, r.values))
        p = _mocap_problem(stamps, ticks, truth, params, step, k=k_nom)
        r, _ = solve_with_variance_components(p)
        nominal.append(_odometry_rms(p, r.values))
    for label, v in (("nominal k", nominal), ("k of the same run", own),
                     ("k of another run", cross)):
        v = np.array(v)
        print(f"{label:<20} odometry-vs-mocap RMS per {step * 50} ms edge: translation "
              f"{np.median(v[:, 0]):.2f} mm (median), rotation {np.median(v[:, 1]):.3f} deg")


def main(argv):
    args = [a for a in argv[1:] if not a.startswith("--")]
    data = Path(args[0]) if args else ROOT.parent / "shared" / "data"
    figures = Path(argv[argv.index("--out") + 1]) if "--out" in argv else ROOT / "docs" / "figures"
    if "--out" in argv:
        args.remove(str(figures))
    figures.mkdir(parents=True, exist_ok=True)
    if not data.exists():
        print(f"no data under {data}; nothing to do")
        return 0
    if "--skip-mines" not in argv:
        mines(data, figures)
    if "--skip-optiodom" not in argv:
        optiodom(data)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
