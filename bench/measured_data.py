"""Calibration and residual diagnosis on the measured data sets (docs/real_data.md).

    .venv/bin/python bench/measured_data.py [DATA_DIR] [--out DIR] [--skip-mines] [--skip-optiodom]

DATA_DIR defaults to ../shared/data beside the repository; a data set that is absent is
skipped with a message (exit 0). Prints the tables quoted in docs/real_data.md and in
the README, and writes the figures to docs/figures/ (or --out).

breezyslam-mines exp1/exp2: converted as logged and with each scan stamped 50–200 ms
before its log line (convert_breezyslam(scan_delay=...): the ticks keep their stamps and
are interpolated at the scan's); per variant the calibration (± σ) and `sclam diagnose`
(default candidate effects, 5-fold time-block held-out NLL). Cross-run: base and extended models
fitted on one run, scored on the other (sclam_ros.diagnosis.cross_run, the metric of
`sclam diagnose --predict`), as logged and with the delay chosen on the fitted run.
optiodom-diff: per run, the mocap calibration (sclam_ros.core.mocap) with and without the
library's time_offset in the graph; open-loop check: dead reckoning over 5 s windows of
every run with nominal k, the run's own k, k of the run's other half (2-fold time blocks),
another run's k and the mean k of the other runs, against motion capture; the tick/mocap lag that minimises the open-loop
heading error, against time_offset.
Repeatability of r_l, r_r, b between runs for both, against the paper's two PowerBot runs.
"""
import sys
from pathlib import Path

import numpy as np

from sclam_ros.diagnosis import cross_run
from sclam_ros.core import mocap
from sclam_ros.io.convert import (
    MINES_TICKS_PER_REV,
    convert_breezyslam,
    optiodom_params,
    read_breezyslam,
    read_optiodom,
)
from sclam_ros.diagnosis.diagnose import diagnose_keyframes
from sclam_ros.diagnosis.effects import LIBRARY, EffectData
from sclam_ros.diagnosis.effects.model import extend_problem
from sclam_ros.diagnosis.figures import write_diagnosis_report
from sclam_ros.core.estimator import calibrate_keyframes
from sclam_ros.io.recording import read_recording
from sclam_ros.core.covariance import marginal_covariance
from sclam_ros.core.params import CALIBRATION_KEYS, SclamParams
from sclam_ros.core.variance_components import solve_with_variance_components

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import scratch_dir  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
WHEELS = CALIBRATION_KEYS[:3]
# Scan stamps tried: each log line's scan taken this long before the line's stamp (s).
SCAN_DELAYS = (0.0, 0.05, 0.10, 0.15, 0.20)
# The paper's two PowerBot runs (wheel base, m): the repeatability reference.
PAPER_BASES = (0.5825, 0.6091)
WINDOW_CYCLES, STRIDE_CYCLES = 100, 20  # OptiOdom: 5 s windows every 1 s at 20 Hz
LAGS = np.round(np.arange(-3.0, 3.0001, 0.1), 1)  # cycles searched for the open-loop lag


def _mm(values, digits=1):
    return ", ".join(f"{v * 1e3:.{digits}f}" for v in values)


def _percent_apart(a, b):
    return 100 * abs(a - b) / (0.5 * (a + b))


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


# --- breezyslam-mines -----------------------------------------------------------------------


def _variant_name(delay):
    return "as logged" if delay == 0 else f"scans {delay * 1e3:.0f} ms earlier"


def _time_offset(report):
    return next(x for x in report["effects"] if x["name"] == "time_offset")


def _mines_variant(src: Path, delay: float, work: Path) -> dict:
    out = work / f"{src.stem}_{delay * 1e3:.0f}ms"
    convert_breezyslam(src, out, scan_delay=delay)
    params = SclamParams.from_yaml(out / "params.yaml")
    keyframes = read_recording(out / "bag", params, keep_scan_points=True).keyframes
    calibration = calibrate_keyframes(keyframes, params)
    diagnosis = diagnose_keyframes(keyframes, params)  # the library's default candidates
    # The clock offset alone, for the trace: among the defaults scan_distortion's sweep
    # delay is the same window shift, and whichever is selected leaves the other undefined.
    offset = _time_offset(diagnose_keyframes(keyframes, params, ["time_offset"]).report)
    return {"keyframes": keyframes, "params": params, "diagnosis": diagnosis, "offset": offset,
            "k": np.array([calibration.estimate[k] for k in WHEELS]),
            "sigma": np.array([calibration.sigma[k] for k in WHEELS])}


def _print_mines_table(variants):
    print("| run, scan stamps | base r_l, r_r, b [mm] | b σ [mm] | base held-out NLL | selected "
          "| time_offset alone [ms] | extended r_l, r_r, b [mm] | extended NLL | unexplained |")
    print("|---|---|---|---|---|---|---|---|---|")
    for (run, delay), v in variants.items():
        rep = v["diagnosis"].report
        b, e = rep["base"], rep["extended"]
        off = v["offset"]
        u = "; ".join(f"{x['component']}~{x['regressor']} {x['strength']:.2f}"
                      for x in rep["unexplained"][:3])
        print(f"| {run} {_variant_name(delay)} | {_mm(b['params'][k] for k in WHEELS)} | "
              f"{v['sigma'][2] * 1e3:.1f} | {b['error']:.3f} | "
              f"{', '.join(cross_run.selected_effects(rep)) or 'none'} | "
              f"{off['value'] * 1e3:.1f} ± {off['sigma'] * 1e3:.1f} | "
              f"{_mm(e['params'][k] for k in WHEELS)} | {e['error']:.3f} | {u or '–'} |")


def _refined_delay(variants, run):
    """The scan delay that run alone points to (so a cross-run prediction never uses the
    predicted run's data): the grid delay with the lowest held-out error of the base
    model, corrected by the clock offset diagnose still fits there (to 5 ms)."""
    best = min((d for r, d in variants if r == run),
               key=lambda d: variants[run, d]["diagnosis"].report["base"]["error"])
    residual = variants[run, best]["offset"]["value"]
    return round(round((best - residual) / 0.005) * 0.005, 3)


def _print_mines_cross_run(variants, runs, chosen):
    print("\nCross-run (fit on one run, score every edge of the other; NLL per edge, lower is "
          "better; the scan delay is the one chosen on the fitted run):\n")
    print("| scan stamps | fit → predict | selected on the fitted run | base | extended "
          "| gain ± s.e. | predicted run's own CV: base, extended |")
    print("|---|---|---|---|---|---|---|")
    for a, b in (runs, runs[::-1]):
        for delay in dict.fromkeys((0.0, chosen[a])):
            fit, other = variants[a, delay], variants[b, delay]
            report = fit["diagnosis"].report
            effects = cross_run.selected_effects(report)
            r = cross_run.cross_run_errors(fit["keyframes"], fit["params"], other["keyframes"],
                                           other["params"], effects)
            own = other["diagnosis"].report
            values = ", ".join(f"{e['name']} {e['value']:.3g} {e['evidence']['units'].split()[0]}"
                               for e in report["effects"] if e["selected"])
            print(f"| {_variant_name(delay)} | {a} → {b} | {values or 'none'} | "
                  f"{r['base']:.3f} | {r['extended']:.3f} | {r['gain']:+.3f} ± {r['gain_stderr']:.3f} | "
                  f"{own['base']['error']:.3f}, {own['extended']['error']:.3f} |")


def _strongest(diagnosis):
    """(component, regressor, |r|) of the strongest residual dependence before the extension."""
    t = max((t for t in diagnosis.tests_before if t["regressor"] != "lag"),
            key=lambda t: t["strength"])
    return t["component"], t["regressor"], t["strength"]


def _mines_trace_figure(variants, runs, path):
    """Held-out error and fitted time_offset against the scan delay given to the converter."""
    plt = _plt()
    fig, (nll_ax, off_ax) = plt.subplots(1, 2, figsize=(10, 3.8))
    for run in runs:
        delays = sorted(d for r, d in variants if r == run)
        reports = [variants[run, d]["diagnosis"].report for d in delays]
        offsets = [variants[run, d]["offset"] for d in delays]
        ms = np.array(delays) * 1e3
        line, = nll_ax.plot(ms, [r["base"]["error"] for r in reports], "o-", label=f"{run} base")
        nll_ax.plot(ms, [r["extended"]["error"] for r in reports], "s--", color=line.get_color(),
                    label=f"{run} extended")
        off_ax.errorbar(ms, [o["value"] * 1e3 for o in offsets],
                        [o["sigma"] * 1e3 for o in offsets], fmt="o-", capsize=3,
                        label=run)
    nll_ax.set_xlabel("scans stamped earlier than their log line [ms]")
    nll_ax.set_ylabel("held-out NLL [nats/edge], lower is better")
    nll_ax.legend(fontsize=7)
    off_ax.axhline(0, color="0.6", lw=0.8)
    off_ax.set_xlabel("scans stamped earlier than their log line [ms]")
    off_ax.set_ylabel("time_offset fitted alone [ms]")
    off_ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    print(f"figure: {path}")


def _mines_residual_figure(variants, runs, chosen, path):
    """Per run: the strongest residual dependence as logged, before (base) and after the
    selected effects, and with the scans re-stamped (base model). Whitened residuals;
    the axes show the central 98 % (failed scan matches reach ±300σ)."""
    plt = _plt()
    fig, axes = plt.subplots(1, len(runs), figsize=(5.2 * len(runs), 3.8), squeeze=False)
    for ax, run in zip(axes[0], runs):
        delay = chosen[run]
        logged, fixed = variants[run, 0.0]["diagnosis"], variants[run, delay]["diagnosis"]
        comp, reg, strength = _strongest(logged)
        shown = []
        for diag, residuals, label in ((logged, logged.residuals_before, "as logged, base"),
                                       (logged, logged.residuals_after,
                                        "as logged + " + ", ".join(cross_run.selected_effects(logged.report))),
                                       (fixed, fixed.residuals_before,
                                        f"{_variant_name(delay)}, base")):
            ax.plot(diag.regressors[reg][diag.edge_of[comp]], residuals[comp], ".", ms=3,
                    alpha=0.6, label=label)
            shown.append(residuals[comp])
        ax.set_ylim(*np.percentile(np.concatenate(shown), [1, 99]) * 1.3)
        ax.set_xlabel(f"{reg} [rad/s]" if reg == "wheel_speed_change" else reg)
        ax.set_ylabel(f"{comp} residual (whitened)")
        ax.set_title(f"{run}: |r| = {strength:.2f} as logged")
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    print(f"figure: {path}")


def _per_line_speed_changes(stamps, ticks):
    """|change| of the wheel speeds Δticks/Δstamp from one log line to the next (rad/s)."""
    speeds = np.diff(ticks, axis=0) / np.diff(stamps)[:, None] * 2 * np.pi / MINES_TICKS_PER_REV
    return np.abs(np.diff(speeds, axis=0))


def _print_tick_stamp_check(runs_src):
    """Do the ticks belong to their own line's stamp? Jittered line intervals make the
    per-line wheel speed smooth only with the stamps the ticks were sampled at."""
    print("Per-line wheel speed change [rad/s], median / 99th percentile: ticks with their own "
          "line's stamp vs with the next line's (each scan paired with the next line's ticks):")
    for src in runs_src:
        stamps, ticks, _ = read_breezyslam(src)
        own = _per_line_speed_changes(stamps, ticks)
        shifted = _per_line_speed_changes(stamps[1:], ticks[:-1])
        dt = np.diff(stamps) * 1e3
        print(f"  {src.stem}: {np.median(own):.1f} / {np.percentile(own, 99):.0f} vs "
              f"{np.median(shifted):.1f} / {np.percentile(shifted, 99):.0f} "
              f"(line intervals {dt.min():.0f}–{dt.max():.0f} ms)")
    print()


def mines(data: Path, figures: Path):
    runs_src = [data / "breezyslam-mines" / f"exp{n}.dat" for n in (1, 2)]
    if not all(p.exists() for p in runs_src):
        print(f"skipping breezyslam-mines: not found under {data}")
        return None
    print("\n## breezyslam-mines\n")
    _print_tick_stamp_check(runs_src)
    work = scratch_dir("mines_")
    variants = {(src.stem, delay): _mines_variant(src, delay, work)
                for src in runs_src for delay in SCAN_DELAYS}
    runs = [src.stem for src in runs_src]
    chosen = {run: _refined_delay(variants, run) for run in runs}
    for delay in set(chosen.values()):  # every run at every chosen delay, for the cross-run
        for src in runs_src:
            if (src.stem, delay) not in variants:
                variants[src.stem, delay] = _mines_variant(src, delay, work)
    variants = dict(sorted(variants.items()))
    print("scan delay each run points to (grid best − time_offset fitted there): "
          + ", ".join(f"{run} {d * 1e3:.0f} ms" for run, d in chosen.items()) + "\n")
    _print_mines_table(variants)
    for run in runs:
        write_diagnosis_report(figures / f"mines_{run}", variants[run, 0.0]["diagnosis"])
    _print_mines_cross_run(variants, runs, chosen)
    print()
    _mines_trace_figure(variants, runs, figures / "mines_scan_delay.png")
    _mines_residual_figure(variants, runs, chosen, figures / "mines_residuals.png")
    return {f"Mines {_variant_name(d)}": [(variants[r, d]["k"], variants[r, d]["sigma"]) for r in runs]
            for d in dict.fromkeys((0.0, *chosen.values()))}


# --- optiodom-diff --------------------------------------------------------------------------


def _with_time_offset(stamps, ticks, truth, params, step=10):
    """The mocap calibration with the library's time_offset in the graph: (k, δ, σ_δ)."""
    inputs = mocap.graph_inputs(stamps, ticks, truth, params.ticks_per_revolution, step)
    nominal_k = params.calibration_vector()[:3]
    angles = np.asarray(ticks, float) * 2 * np.pi / params.ticks_per_revolution
    speeds = np.gradient(angles, stamps, axis=0)
    data = EffectData(inputs.stamps, np.column_stack(
        [np.interp(inputs.stamps, stamps, speeds[:, c]) for c in range(2)]))
    problem = extend_problem(mocap.build_problem(inputs, params, nominal_k),
                             [LIBRARY["time_offset"](data)])
    result, _ = solve_with_variance_components(problem)
    cov = marginal_covariance(problem, result.values, ["time_offset"])
    return result.values["odometry"][0], result.values["time_offset"][0][0], float(np.sqrt(cov[0, 0]))


def _aligned_mount(run, k, params):
    """The marker mount refitted on this run with k held: each k gets its best alignment."""
    stamps, truth, ticks = run
    return mocap.calibrate_with_ground_truth(stamps, ticks, truth, params, fixed_k=k).estimate[3:]


def _open_loop(run, k, params, lag=0.0, mount=None):
    """RMS over 5 s windows of the dead-reckoning end error (mm, deg) with k."""
    _, truth, ticks = run
    mount = _aligned_mount(run, k, params) if mount is None else mount
    trans, heading = mocap.dead_reckoning_errors(ticks, truth, k, mount, params.ticks_per_revolution,
                                                 WINDOW_CYCLES, STRIDE_CYCLES, lag)
    return np.sqrt(np.mean(trans ** 2)) * 1e3, np.degrees(np.sqrt(np.mean(heading ** 2)))


def _halves(run):
    middle = len(run[0]) // 2
    return tuple(a[:middle] for a in run), tuple(a[middle:] for a in run)


def _two_fold(run, params):
    """Time-block cross-validation within the run: k fitted on one half, dead reckoning
    scored on the other, both ways (RMS of the two halves' RMS)."""
    errors = []
    for train, test in (_halves(run), _halves(run)[::-1]):
        stamps, truth, ticks = train
        k = mocap.calibrate_with_ground_truth(stamps, ticks, truth, params).estimate[:3]
        errors.append(_open_loop(test, k, params))
    return tuple(np.sqrt(np.mean(np.square(errors), axis=0)))


def _optiodom_calibrations(loaded, params):
    print("| run | r_l, r_r, b ± σ [mm] | marker x, y [mm], yaw [deg] | time_offset [ms] | "
          "r_l, r_r, b with time_offset [mm] |")
    print("|---|---|---|---|---|")
    fits = {}
    for name, (stamps, truth, ticks) in loaded.items():
        cal = mocap.calibrate_with_ground_truth(stamps, ticks, truth, params)
        k1, offset, offset_sigma = _with_time_offset(stamps, ticks, truth, params)
        fits[name] = dict(k=cal.estimate[:3], sigma=cal.sigma[:3], mount=cal.estimate[3:],
                          offset=offset, offset_sigma=offset_sigma)
        k_text = ", ".join(f"{x * 1e3:.2f} ± {s * 1e3:.2f}" for x, s in zip(cal.estimate[:3], cal.sigma[:3]))
        m = cal.estimate[3:]
        print(f"| {name} | {k_text} | {m[0] * 1e3:.1f}, {m[1] * 1e3:.1f}, {np.degrees(m[2]):.2f} | "
              f"{offset * 1e3:.1f} ± {offset_sigma * 1e3:.1f} | {', '.join(f'{x * 1e3:.2f}' for x in k1)} |")
    return fits


def _optiodom_open_loop(loaded, fits, params):
    print(f"\nOpen loop: dead reckoning over {WINDOW_CYCLES * 0.05:.0f} s windows (one every "
          f"{STRIDE_CYCLES * 0.05:.0f} s), started at the mocap pose; RMS of the end error, "
          "translation [mm] / heading [deg]:\n")
    print("| run | nominal k | same run's k | same run, other half's k | other runs of the same "
          "shape: median | runs of the other shape: median | any other run: heading best – worst "
          "(worst k) | mean k of the 11 others |")
    print("|---|---|---|---|---|---|---|---|")
    nominal = np.array(params.calibration_vector()[:3])
    table = {}
    for b, run in loaded.items():
        others = [a for a in loaded if a != b]
        cross = np.array([_open_loop(run, fits[a]["k"], params) for a in others])
        same_shape = np.array([a[:4] == b[:4] for a in others])
        row = {"nominal": _open_loop(run, nominal, params),
               "same run": _open_loop(run, fits[b]["k"], params),
               "other half": _two_fold(run, params),
               "same shape (median)": tuple(np.median(cross[same_shape], 0)),
               "other shape (median)": tuple(np.median(cross[~same_shape], 0)),
               "mean of the others": _open_loop(run, np.mean([fits[a]["k"] for a in others], 0), params),
               "worst other": others[int(np.argmax(cross[:, 1]))], "cross": cross}
        table[b] = row
        f = lambda v: f"{v[0]:.1f} / {v[1]:.2f}"
        print(f"| {b} | {f(row['nominal'])} | {f(row['same run'])} | {f(row['other half'])} | "
              f"{f(row['same shape (median)'])} | "
              f"{f(row['other shape (median)'])} | {cross[:, 1].min():.2f} – {cross[:, 1].max():.2f}° "
              f"({row['worst other']}) | {f(row['mean of the others'])} |")
    keys = ("nominal", "same run", "other half", "same shape (median)", "other shape (median)",
            "mean of the others")
    med = {key: np.median([row[key] for row in table.values()], 0) for key in keys}
    cells = [f"{med[k][0]:.1f} / {med[k][1]:.2f}" for k in keys]
    print("| median over runs | " + " | ".join(cells[:5] + ["–"] + cells[5:]) + " |")
    return table


def _optiodom_lags(loaded, fits, params):
    print("\nTick/mocap lag: the lag (cycles of 50 ms, fractional by interpolating the ticks) "
          "that minimises the open-loop heading error with the run's own k, against the "
          "time_offset fitted in the graph:\n")
    print("| run | open-loop lag [ms] | heading RMS at lag 0 → at best [deg] | time_offset [ms] |")
    print("|---|---|---|---|")
    for name, run in loaded.items():
        fit = fits[name]
        mount = _aligned_mount(run, fit["k"], params)
        heading = [_open_loop(run, fit["k"], params, lag, mount)[1] for lag in LAGS]
        best = LAGS[int(np.argmin(heading))]
        at_edge = " (search edge)" if abs(best) == LAGS.max() else ""
        print(f"| {name} | {best * 50:.0f}{at_edge} | {heading[len(LAGS) // 2]:.2f} → {min(heading):.2f} | "
              f"{fit['offset'] * 1e3:.1f} ± {fit['offset_sigma'] * 1e3:.1f} |")


def _optiodom_figure(table, path):
    plt = _plt()
    names = list(table)
    keys = ("nominal", "same run", "other half", "same shape (median)", "other shape (median)",
            "mean of the others")
    width = 0.8 / len(keys)
    offsets = (np.arange(len(keys)) - (len(keys) - 1) / 2) * width
    fig, axes = plt.subplots(2, 1, figsize=(11, 6), sharex=True)
    x = np.arange(len(names))
    for c, (ax, unit) in enumerate(zip(axes, ("translation [mm]", "heading [deg]"))):
        for offset, key in zip(offsets, keys):
            ax.bar(x + offset, [table[name][key][c] for name in names], width, label=f"k: {key}")
        spread = np.array([[table[n]["cross"][:, c].min(), table[n]["cross"][:, c].max()] for n in names])
        ax.vlines(x + offsets[keys.index("other shape (median)")], spread[:, 0], spread[:, 1],
                  color="k", lw=1, label="k of any other run: best – worst")
        ax.set_ylabel(f"5 s end error, {unit}")
    axes[0].legend(fontsize=7, ncol=3)
    axes[1].set_xticks(x, names)
    fig.suptitle("OptiOdom: dead reckoning over 5 s windows vs motion capture (RMS per run)")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    print(f"\nfigure: {path}")


def optiodom(data: Path, figures: Path):
    runs = sorted((data / "optiodom-diff").glob("*/*/*_run-??.csv"))
    if not runs:
        print(f"skipping optiodom-diff: no runs under {data}")
        return None
    print("\n## optiodom-diff\n")
    params = optiodom_params()
    loaded = {path.parent.parent.name[:4] + path.stem[-2:]: read_optiodom(path) for path in runs}
    fits = _optiodom_calibrations(loaded, params)
    table = _optiodom_open_loop(loaded, fits, params)
    _optiodom_figure(table, figures / "optiodom_dead_reckoning.png")
    _optiodom_lags(loaded, fits, params)
    return {"circular": [(f["k"], f["sigma"]) for n, f in fits.items() if n.startswith("circ")],
            "square": [(f["k"], f["sigma"]) for n, f in fits.items() if n.startswith("squa")]}


# --- repeatability -------------------------------------------------------------------------


def _pairwise(estimates):
    """Per pair of runs: |Δb| in % of their mean and in combined σ."""
    out = []
    for i in range(len(estimates)):
        for j in range(i + 1, len(estimates)):
            (ki, si), (kj, sj) = estimates[i], estimates[j]
            out.append((_percent_apart(ki[2], kj[2]), abs(ki[2] - kj[2]) / np.hypot(si[2], sj[2])))
    return np.array(out)


def repeatability(sets: dict, figures: Path):
    print("\n## repeatability between runs\n")
    print("| data set | runs | r_l, r_r, b mean [mm] | sd over runs [mm] | b apart [%]: median (max) "
          "| b apart in combined σ: median (max) |")
    print("|---|---|---|---|---|---|")
    a, b = PAPER_BASES
    print(f"| paper, PowerBot | 2 | –, –, {0.5e3 * (a + b):.1f} | – | {_percent_apart(a, b):.1f} | – |")
    pooled = [e for name, est in sets.items() if name.startswith("OptiOdom") for e in est]
    rows = {**sets, **({"OptiOdom, all runs": pooled} if pooled else {})}
    for name, estimates in rows.items():
        k = np.array([e[0] for e in estimates])
        pairs = _pairwise(estimates)
        print(f"| {name} | {len(k)} | {_mm(k.mean(0), 2)} | {_mm(k.std(0, ddof=1), 2)} | "
              f"{np.median(pairs[:, 0]):.1f} ({pairs[:, 0].max():.1f}) | "
              f"{np.median(pairs[:, 1]):.1f} ({pairs[:, 1].max():.1f}) |")
    _repeatability_figure(sets, figures / "repeatability.png")


def _repeatability_figure(sets, path):
    """Per parameter: each run's estimate ± σ in % of its data set's mean."""
    plt = _plt()
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.8), sharey=True)
    for ax, c, label in zip(axes, range(3), ("r_l", "r_r", "b")):
        x0 = 0
        for name, estimates in sets.items():
            k = np.array([e[0][c] for e in estimates])
            s = np.array([e[1][c] for e in estimates])
            x = x0 + np.arange(len(k))
            ax.errorbar(x, 100 * (k / k.mean() - 1), 100 * s / k.mean(), fmt="o", ms=4,
                        capsize=2, label=name)
            x0 += len(k) + 1
        if label == "b":
            paper = np.array(PAPER_BASES)
            ax.plot(x0 + np.arange(2), 100 * (paper / paper.mean() - 1), "k*", ms=9,
                    label="paper, PowerBot")
        ax.axhline(0, color="0.7", lw=0.8)
        ax.set_title(f"{label}: run estimate ± 1σ")
        ax.set_xticks([])
    axes[0].set_ylabel("% from the data set's mean")
    axes[2].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    print(f"\nfigure: {path}")


def main(argv):
    args = [a for a in argv[1:] if not a.startswith("--")]
    figures = Path(argv[argv.index("--out") + 1]) if "--out" in argv else ROOT / "docs" / "figures"
    if "--out" in argv:
        args.remove(argv[argv.index("--out") + 1])
    data = Path(args[0]) if args else ROOT.parent / "shared" / "data"
    figures.mkdir(parents=True, exist_ok=True)
    if not data.exists():
        print(f"no data under {data}; nothing to do")
        return 0
    sets = {}
    if "--skip-mines" not in argv:
        sets.update(mines(data, figures) or {})
    if "--skip-optiodom" not in argv:
        sets.update({f"OptiOdom {k}": v for k, v in (optiodom(data, figures) or {}).items()})
    if sets:
        repeatability(sets, figures)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
