"""``sclam convert {breezyslam,optiodom} SRC OUT``: turn a published real-robot log into
a rosbag2 this package reads.

OUT receives ``bag/`` (the rosbag2), ``params.yaml`` (the documented nominal parameters)
and ``ATTRIBUTION.md`` (source, commit and licence; keep it with the data).

  breezyslam  SRC = exp1.dat / exp2.dat of BreezySLAM: /joint_states (cumulative ticks)
              and /scan (Hokuyo URG-04LX, frame 'laser')
  optiodom    SRC = <id>_run-NN.csv of OptiOdom: /joint_states (cumulative ticks) and
              /mocap/odom (motion-capture ground truth); no laser
  carmen      SRC = a CARMEN log (.clf, optionally .bz2/.gz; ODOM, FLASER, ROBOTLASER1,
              PARAM): /joint_states (wheel angles implied from the logged odometry with
              the nominal radius and wheel base), /scan and /odom (the log's odometry)
"""
from __future__ import annotations

import argparse
import math


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from sclam_ros.io.convert import CONVERTERS

    parser.add_argument("format", choices=sorted(CONVERTERS), help="source log format")
    parser.add_argument("src", help="source file")
    parser.add_argument("out", help="output folder (OUT/bag must not exist)")
    parser.add_argument("--storage", choices=("sqlite3", "mcap"), default="sqlite3",
                        help="rosbag2 storage (default: %(default)s)")
    parser.add_argument("--scan-delay", type=float, default=0.0, metavar="S",
                        help="breezyslam and carmen: each scan was taken S seconds before its log "
                             "line (the Mines logs: 0.16, found by sclam diagnose; the ACES log: "
                             "0.1, from its ground truth; default 0)")
    parser.add_argument("--fov", type=float, default=None, metavar="DEG",
                        help="carmen: the span of an FLASER line's beams, first to last (the "
                             "log does not state it; default 180, as CARMEN's own reader)")
    parser.add_argument("--nominal-radius", type=float, default=None, metavar="M",
                        help="carmen only: wheel radius the wheel rotations are implied with "
                             "(default 0.1 m)")
    parser.add_argument("--nominal-base", type=float, default=None, metavar="M",
                        help="carmen only: wheel base the wheel rotations are implied with "
                             "(default 0.4 m)")


def run(args) -> int:
    """Input errors (ConvertError, BagError) propagate to sclam_ros.cli.main: one line, exit 2."""
    from sclam_ros.cli.main import CommandError
    from sclam_ros.io.convert import CONVERTERS

    if args.scan_delay and args.format not in ("breezyslam", "carmen"):
        raise CommandError("--scan-delay applies to breezyslam and carmen logs only")
    nominal = {"radius": args.nominal_radius, "base": args.nominal_base}
    if any(v is not None for v in nominal.values()) and args.format != "carmen":
        raise CommandError("--nominal-radius and --nominal-base apply to carmen logs only")
    if args.fov is not None and not (args.format == "carmen" and 0 < args.fov <= 360):
        raise CommandError("--fov applies to carmen logs only, in (0, 360] degrees")
    for name, value in nominal.items():
        if value is not None and not (0 < value < 10):
            raise CommandError(f"--nominal-{name} must be in (0, 10) m, got {value}")
    options = {"scan_delay": args.scan_delay} if args.format == "breezyslam" else {}
    if args.format == "carmen":
        options = {k: v for k, v in nominal.items() if v is not None}
        options["scan_delay"] = args.scan_delay
        if args.fov is not None:
            options["fov"] = math.radians(args.fov)
    summary = CONVERTERS[args.format](args.src, args.out, args.storage, **options)
    print(f"wrote {args.out}/bag, params.yaml, ATTRIBUTION.md: "
          + ", ".join(f"{k} {v:.1f}" if isinstance(v, float) else f"{k} {v}"
                      for k, v in summary.items()))
    return 0
