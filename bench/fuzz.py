"""Never crash, never silently wrong (issue 13): the fuzz matrix.

Every case of test/fuzz_cases.py (bad scans, wrong topics, unusable parameters files,
corrupt storage, miswired encoders, foreign clocks, degenerate motion, ...) is made from a
short simulated recording and run through `sclam calibrate` and `sclam calibrate --track`
as subprocesses. Per case: what it declares it must give, what each run gave (traceback,
nan, error, warning, unobservable(...) with the parameters flagged, clean; WRONG(...) for an
exit-0 estimate more than 5σ from the truth) and pass/fail; then the totals and, for each
failing run, its reason line or warnings.

Run: .venv/bin/python bench/fuzz.py [--jobs 2] [--cases NAME ...] [--work DIR]
"""
from __future__ import annotations

import argparse
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "test"))
sys.path.insert(0, str(Path(__file__).resolve().parent))
import fuzz_cases as fuzz  # noqa: E402
from common import scratch_dir, table  # noqa: E402


def _source(args):
    name, folder = args
    fuzz.make_source(name, folder)
    return name


def _run(args):
    name, sources, work, track = args
    start = time.perf_counter()
    try:
        outcome = fuzz.run(fuzz.CASES[name], sources, work, track)
    except Exception as exc:  # noqa: BLE001 - a broken case generator fails its row, not the bench
        outcome = fuzz.Outcome("case_not_made", f"{type(exc).__name__}: {exc}")
    return name, track, outcome, time.perf_counter() - start


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--jobs", type=int, default=2, help="worker processes (default 2)")
    parser.add_argument("--cases", nargs="+", choices=sorted(fuzz.CASES), metavar="NAME",
                        help="only these cases (default: all)")
    parser.add_argument("--work", help="folder for the recordings (default: a temporary one)")
    args = parser.parse_args()
    names = args.cases or list(fuzz.CASES)
    work = Path(args.work or scratch_dir("sclam_fuzz_"))
    sources = work / "sources"
    sources.mkdir(parents=True, exist_ok=True)
    needed = sorted({fuzz.CASES[n].source for n in names} | {"good"})
    start = time.perf_counter()
    outcomes = {}
    seconds = {}
    with ProcessPoolExecutor(args.jobs) as pool:
        list(pool.map(_source, [(name, sources) for name in needed]))
        tasks = [(n, sources, work / "cases", track) for n in names for track in (False, True)]
        for name, track, outcome, spent in pool.map(_run, tasks):
            outcomes[name, track] = outcome
            seconds[name, track] = spent
            print(f"  {name} {'--track' if track else 'batch'}: {outcome.short()} "
                  f"({spent:.1f} s)", file=sys.stderr, flush=True)

    rows, failures = [], []
    totals = dict(runs=0, failed=0, tracebacks=0, nan=0, silently_wrong=0)
    for name in names:
        case = fuzz.CASES[name]
        row_pass = True
        for track in (False, True):
            outcome = outcomes[name, track]
            ok = fuzz.judge(case, outcome)
            totals["runs"] += 1
            totals["failed"] += not ok
            totals["tracebacks"] += outcome.kind == "traceback"
            totals["nan"] += outcome.kind == "nan"
            totals["silently_wrong"] += fuzz.silently_wrong(case, outcome)
            row_pass &= ok
            if not ok:
                failures.append((name, "--track" if track else "batch", outcome))
        expected = "/".join((case.expect, *case.also))
        if case.needles:
            expected += " [" + "; ".join(case.needles) + "]"
        rows.append((name, expected, outcomes[name, False].short(), outcomes[name, True].short(),
                     "pass" if row_pass else "FAIL"))
    print(f"Fuzz matrix: {len(names)} cases from a {fuzz.SOURCE_DURATION:.0f} s simulated "
          f"recording (pioneer, seed 2), each through `sclam calibrate` (batch) and "
          f"`sclam calibrate --track`, {args.jobs} worker processes, "
          f"{time.perf_counter() - start:.0f} s wall.\n")
    print(table(rows, ("case", "expected [named]", "batch", "--track", "result")))
    print(f"\nruns: {totals['runs']}, failed: {totals['failed']}; tracebacks: "
          f"{totals['tracebacks']}, NaN: {totals['nan']}, silently wrong (exit 0, wrong or "
          f"the problem unnamed): {totals['silently_wrong']}")
    if failures:
        print("\nFailing runs:")
        for name, mode, outcome in failures:
            print(f"- {name} ({mode}): {outcome.short()}: {outcome.detail or '(nothing said)'}")
    return 1 if totals["failed"] else 0


if __name__ == "__main__":
    sys.exit(main())
