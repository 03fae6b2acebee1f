"""``sclam convert {breezyslam,optiodom} SRC OUT``: turn a published real-robot log into
a rosbag2 this package reads.

OUT receives ``bag/`` (the rosbag2), ``params.yaml`` (the documented nominal parameters)
and ``ATTRIBUTION.md`` (source, commit and licence; keep it with the data).

  breezyslam  SRC = exp1.dat / exp2.dat of BreezySLAM: /joint_states (cumulative ticks)
              and /scan (Hokuyo URG-04LX, frame 'laser')
  optiodom    SRC = <id>_run-NN.csv of OptiOdom: /joint_states (cumulative ticks) and
              /mocap/odom (motion-capture ground truth); no laser
"""
from __future__ import annotations

import argparse


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from sclam_ros.io.convert import CONVERTERS

    parser.add_argument("format", choices=sorted(CONVERTERS), help="source log format")
    parser.add_argument("src", help="source file")
    parser.add_argument("out", help="output folder (OUT/bag must not exist)")
    parser.add_argument("--storage", choices=("sqlite3", "mcap"), default="sqlite3",
                        help="rosbag2 storage (default: %(default)s)")
    parser.add_argument("--scan-delay", type=float, default=0.0, metavar="S",
                        help="breezyslam only: each scan was taken S seconds before its log line "
                             "(the Mines logs: 0.16, found by sclam diagnose; default 0)")


def run(args) -> int:
    """Input errors (ConvertError, BagError) propagate to sclam_ros.cli.main: one line, exit 2."""
    from sclam_ros.cli.main import CommandError
    from sclam_ros.io.convert import CONVERTERS

    if args.scan_delay and args.format != "breezyslam":
        raise CommandError("--scan-delay applies to breezyslam logs only")
    options = {"scan_delay": args.scan_delay} if args.format == "breezyslam" else {}
    summary = CONVERTERS[args.format](args.src, args.out, args.storage, **options)
    print(f"wrote {args.out}/bag, params.yaml, ATTRIBUTION.md: "
          + ", ".join(f"{k} {v:.1f}" if isinstance(v, float) else f"{k} {v}"
                      for k, v in summary.items()))
    return 0
