"""``sclam diagnose BAG --params PARAMS.yaml --json OUT.json [--report DIR] [--predict OTHER_BAG]``:
is the model enough?

Calibrates the recording (the base model), tests its residuals for structure (whiteness,
dependence on speed, turn rate, acceleration, time, distance, position, wheel angle),
fits every effect of the library (sclam_ros/diagnosis/effects) jointly with the calibration, selects
those that lower the error on held-out time blocks and pass a BIC check, refits with them
and reports what is still unexplained. --report writes residual-vs-regressor figures,
before and after. --predict scores another recording of the same robot with the base and
extended models fitted on BAG (sclam_ros.diagnosis.cross_run): the error across runs, in
``base.error_cross_run`` / ``extended.error_cross_run``.
"""
from __future__ import annotations

import argparse
import json
import logging

log = logging.getLogger("sclam")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("bag", help="rosbag2 folder, or its .db3 / .mcap file")
    parser.add_argument("--params", required=True, metavar="PARAMS.yaml",
                        help="ROS 2 parameters file for node 'sclam' (topics, joints, nominal values)")
    parser.add_argument("--json", metavar="OUT.json", help="write the diagnosis as JSON")
    parser.add_argument("--report", metavar="DIR", help="write residual figures (PNG) here")
    from sclam_ros.diagnosis.config import SelectionConfig
    from sclam_ros.diagnosis.effects import LIBRARY

    parser.add_argument("--effects", metavar="NAME[,NAME...]",
                        help=f"effects to try (default: {','.join(LIBRARY)})")
    parser.add_argument("--folds", type=int, default=SelectionConfig().folds,
                        help="time blocks of the cross-validation (mean effects)")
    parser.add_argument("--noise-folds", type=int, default=SelectionConfig().noise_folds,
                        help="folds of the noise effects' cross-validation, each of blocks "
                             "spread over the run")
    parser.add_argument("--predict", metavar="OTHER_BAG",
                        help="another recording of the same robot: fit on BAG, report the error on it")
    parser.add_argument("--predict-params", metavar="PARAMS.yaml",
                        help="parameters file for OTHER_BAG (default: --params)")
    parser.add_argument("--quiet", action="store_true", help="no progress output")


def _likelihood_ratio(evidence) -> str:
    """The likelihood ratio the effect was judged by, against its penalty."""
    text = f"LR {evidence['likelihood_ratio']:.1f} vs BIC {evidence['bic_penalty']:.1f}"
    if "heldout_penalty" in evidence:  # a searched effect (a region)
        text += (f", held-out LR {evidence['heldout_likelihood_ratio']:.1f} vs "
                 f"{evidence['heldout_penalty']:.1f}")
    return text


def _region_text(region) -> str:
    """Where a noise region lies (odometry frame), and how well walls bound it."""
    corners = ", ".join(f"({x:.1f}, {y:.1f})" for x, y in region["corners"])
    support = region.get("wall_support")
    walls = ("no scans kept for a map of walls" if support is None else
             f"walls bound it {support:.0%} (left through doors, no wall through it)")
    return f"region: corners {corners} m in the odometry frame; {walls}"


def format_summary(report, config=None) -> str:
    """The report in lines for a reader; `config`: the DiagnoseConfig it was made with
    (default: DiagnoseConfig())."""
    from sclam_ros.diagnosis.config import DiagnoseConfig

    sigma_ratio = (config or DiagnoseConfig()).identifiability.sigma_ratio

    lines = [f"held-out error: base {report['base']['error']:.4f}, "
             f"extended {report['extended']['error']:.4f}"]
    if "error_cross_run" in report["extended"]:
        ext = report["extended"]
        lines.append(f"cross-run error (fitted here, scored on the other recording, "
                     f"{ext['cross_run_edges']} edges): base {report['base']['error_cross_run']:.4f}, "
                     f"extended {ext['error_cross_run']:.4f} "
                     f"(gain ± stderr {report['base']['error_cross_run'] - ext['error_cross_run']:+.4f} "
                     f"± {ext['cross_run_gain_stderr']:.4f})")
    for e in report["effects"]:
        sigma = "" if e["sigma"] is None else f" ± {e['sigma']:.4g}"
        lines.append(f"  {'SELECTED ' if e['selected'] else 'rejected '}{e['name']:<16}"
                     f"{e['value']:.4g}{sigma} {e['evidence']['units']}  "
                     f"(held-out gain {e['evidence']['heldout_gain_per_edge']:+.4f}/edge, "
                     f"{_likelihood_ratio(e['evidence'])})")
        if e["selected"] and e.get("region"):
            lines.append("    " + _region_text(e["region"]))
        alternatives = e["evidence"].get("alternatives")
        if alternatives and e["selected"]:
            lines.append(f"    {', '.join(alternatives)} fit the data about as well (within one "
                         f"standard error of held-out error); {e['name']} is the simplest of them")
        ident = e["evidence"]["identifiability"]
        if not e["selected"] and not ident["determined"] and ident["sigma_ratio"] is not None:
            lines.append(f"    not determined by this recording: its σ is "
                         f"{ident['sigma_ratio']:.2f} of its prior's (at most "
                         f"{sigma_ratio} to join)")
        stand_in = e["evidence"].get("stand_in_for")
        if stand_in and not e["selected"]:
            lines.append(f"    {stand_in['regressor']} explains more of what it would fit "
                         f"({stand_in['fraction_explained']:.0%} against "
                         f"{stand_in['signature_fraction']:.0%}): it would only stand in for it")
    if report["unexplained"]:
        lines.append("unexplained structure:")
        lines += [f"  {u['component']} vs {u['regressor']}: strength {u['strength']:.2f}"
                  for u in report["unexplained"]]
    else:
        lines.append("no unexplained structure in the residual tests")
    if report.get("scan_matcher_structure"):
        lines.append("the scan matches' residuals depend on how the robot moves (the scan "
                     "matcher's error, not counted as the model's: docs/diagnose.md): " + ", ".join(
                         f"{u['component']} vs {u['regressor']} {u['strength']:.2f}"
                         for u in report["scan_matcher_structure"]))
    for cause in report.get("unexplained_cause", [])[:1]:
        # The naming test fits each regressor as an additive and as a scale error
        # (diagnosis/structure.py), so it can find structure the tests above do not.
        found = "" if report["unexplained"] else (
            " (found by the naming test, which fits each regressor as an additive and as a "
            "scale error)")
        lines.append(f"unexplained odometry structure named by {cause['regressor']} "
                     f"({cause['fraction_explained']:.0%} of it explained){found}")
    lines += [f"warning: {w}" for w in report.get("warnings", [])]
    return "\n".join(lines)


def run(args) -> int:
    """Input errors propagate to sclam_ros.cli.main: one line, exit status 2."""
    from sclam_ros.diagnosis.cross_run import add_cross_run
    from sclam_ros.diagnosis.diagnose import diagnose_keyframes
    from sclam_ros.diagnosis.effects import LIBRARY
    from sclam_ros.diagnosis.figures import write_diagnosis_report
    from sclam_ros.io.recording import read_recording
    from sclam_ros.core.params import SclamParams, atomic_write_text
    from sclam_ros.cli.main import CommandError
    from sclam_ros.cli.progress import ProgressBar

    names = [n.strip() for n in args.effects.split(",")] if args.effects else None
    unknown = [n for n in names or [] if n not in LIBRARY]
    if unknown:
        raise CommandError(f"unknown effect(s) {unknown}; known: {', '.join(LIBRARY)}")
    params = SclamParams.from_yaml(args.params)
    recording = read_recording(args.bag, params,
                               progress=ProgressBar("reading + scan matching", not args.quiet),
                               keep_scan_points=True)
    diagnosis = diagnose_keyframes(recording.keyframes, params, names, folds=args.folds,
                                   noise_folds=args.noise_folds, progress=None if args.quiet else log.info)
    if args.predict:
        other_params = SclamParams.from_yaml(args.predict_params or args.params)
        other = read_recording(args.predict, other_params,
                               progress=ProgressBar("reading + scan matching (--predict)",
                                                    not args.quiet))
        add_cross_run(diagnosis.report, recording.keyframes, params, other.keyframes,
                      other_params, args.predict)
    print(format_summary(diagnosis.report, diagnosis.config))
    if args.json:
        atomic_write_text(args.json, json.dumps(diagnosis.report, indent=2) + "\n")
    if args.report:
        for path in write_diagnosis_report(args.report, diagnosis):
            log.info("wrote %s", path)
    return 0
