"""``sclam fleet INPUT... --out DIR``: calibrate many recordings on Dask distributed.
``sclam fleet report DIR``: each robot's calibrations over time, and the changes.

INPUT: rosbag2 folders or storage files, folders searched for them (a fleet stored as
ROBOT/BAG: the robot is the folder's name), or a manifest CSV with columns robot, bag, params.
Each recording is one task on a Dask LocalCluster (one worker process per core, or --workers),
or on an existing cluster (--scheduler tcp://HOST:8786). Results go to DIR/recordings/*.json
and DIR/results.csv; a rerun calibrates only the recordings whose files changed or that have
no result yet. A recording that fails is a failed row with its reason; the others go on.
Exit status: the number of failed recordings (capped at 100), 0 when all succeeded; 2 with one
error line when the inputs name no usable recording.
"""
from __future__ import annotations

import logging
import sys
from pathlib import Path

log = logging.getLogger("sclam")

MAX_EXIT_STATUS = 100


def add_arguments(parser) -> None:
    parser.add_argument("inputs", nargs="+", metavar="INPUT",
                        help="bags, folders of bags, or manifest CSVs; or `report DIR`")
    parser.add_argument("--out", metavar="DIR", help="results folder (required to calibrate)")
    parser.add_argument("--params", metavar="PARAMS.yaml",
                        help="parameters for recordings the manifest gives none "
                             "(default: a params.yaml inside or beside each bag)")
    parser.add_argument("--workers", type=int, default=None,
                        help="worker processes of the local cluster (default: one per core)")
    parser.add_argument("--scheduler", metavar="tcp://HOST:8786",
                        help="run on this existing Dask cluster instead of a local one")
    parser.add_argument("--quiet", action="store_true", help="no progress output")


def run(args) -> int:
    if args.inputs[0] == "report":
        if len(args.inputs) != 2:
            return _error("usage: sclam fleet report DIR")
        return report(Path(args.inputs[1]))
    if not args.out:
        return _error("--out DIR is required (where results.csv and the JSONs go)")
    if args.workers is not None and args.workers < 1:
        return _error("--workers must be at least 1")
    return calibrate_fleet(args)


def _error(message: str) -> int:
    print(f"sclam fleet: error: {message}", file=sys.stderr)
    return 2


def calibrate_fleet(args) -> int:
    from sclam_ros.cli.progress import ProgressBar
    from sclam_ros.fleet.engine import dask_client
    from sclam_ros.fleet.recordings import RecordingsError, collect
    from sclam_ros.fleet.runner import run_fleet
    from sclam_ros.fleet.store import ResultStore

    try:
        recordings = collect(args.inputs, args.params)
    except (RecordingsError, OSError) as exc:
        return _error(str(exc))
    if not recordings:
        return _error("the inputs name no recording")
    store = ResultStore(args.out)
    log.info("%d recording(s) of %d robot(s)", len(recordings), len({r.robot for r in recordings}))
    with dask_client(args.workers, args.scheduler, dashboard=not args.quiet) as client:
        summary = run_fleet(client, recordings, store,
                            ProgressBar("calibrating recordings", not args.quiet))
    print(f"{summary.total} recording(s): {summary.calibrated} calibrated, "
          f"{summary.reused} unchanged since the last run (result kept), "
          f"{len(summary.failed)} failed")
    for bag, reason in summary.failed:
        print(f"  FAILED {bag}: {reason}")
    for bag, reason in summary.failed_before:
        print(f"  FAILED (unchanged since the last run) {bag}: {reason}")
    print(f"results: {store.folder / 'results.csv'}")
    return min(len(summary.failed) + len(summary.failed_before), MAX_EXIT_STATUS)


def report(folder: Path) -> int:
    from sclam_ros.fleet.history import changes, format_history, plot_history
    from sclam_ros.fleet.store import ResultStore

    if not (folder / "recordings").is_dir():
        return _error(f"{folder} holds no fleet results (no recordings/ folder)")
    results = ResultStore(folder).all_results()
    found = changes(results)
    print(format_history(results, found))
    failed = [r for r in results if r["status"] != "ok"]
    if failed:
        print(f"\n{len(failed)} recording(s) failed and are not in the history:")
        for r in failed:
            print(f"  {r['bag']}: {r['error']}")
    figure = folder / "history.png"
    plot_history(results, found, figure)
    changes_csv = folder / "changes.csv"
    _write_changes(changes_csv, found)
    print(f"figure: {figure}\nchanges: {changes_csv}")
    return 0


def _write_changes(path: Path, found) -> None:
    import csv
    import io

    from sclam_ros.core.params import atomic_write_text

    buffer = io.StringIO()
    writer = csv.writer(buffer)
    writer.writerow(["robot", "parameter", "bag_before", "bag_after", "before", "after", "sigmas"])
    for c in found:
        writer.writerow([c.robot, c.parameter, c.bag_before, c.bag_after,
                         f"{c.before:.9g}", f"{c.after:.9g}", f"{c.sigmas:.2f}"])
    atomic_write_text(path, buffer.getvalue())
