"""``sclam export CALIBRATION.json --format urdf|diff-drive|params``: apply a calibration.

Writes what `sclam calibrate --json` estimated in the formats a robot loads:
  urdf        the fixed joint base frame -> laser frame with the calibrated <origin>
              (x, y, yaw; z, roll and pitch are not calibrated: keep your URDF's)
  diff-drive  a ros2_control diff_drive_controller parameter block: wheel_separation,
              wheel_radius (the mean radius) and left/right_wheel_radius_multiplier
  params      this package's parameters YAML with the calibrated values as nominal
A parameter the recording did not observe keeps its nominal value and is named in the output.
"""
from __future__ import annotations

import argparse
import logging

log = logging.getLogger("sclam")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from sclam_ros.io.export import DEFAULT_CONTROLLER, FORMATS

    parser.add_argument("calibration", metavar="CALIBRATION.json",
                        help="the output of `sclam calibrate --json`")
    parser.add_argument("--format", required=True, choices=FORMATS)
    parser.add_argument("--params", metavar="PARAMS.yaml",
                        help="the parameters file the calibration started from (needed for "
                             "--format params; otherwise it supplies the base frame and nominal "
                             "values a calibration file lacks)")
    parser.add_argument("--controller", default=DEFAULT_CONTROLLER, metavar="NAME",
                        help="the controller's name for --format diff-drive (default: %(default)s)")
    parser.add_argument("--out", metavar="FILE", help="write here instead of printing")


def run(args) -> int:
    """ExportError and ParamsError end in one line and exit status 2 (sclam_ros.cli.main)."""
    from sclam_ros.core.params import SclamParams, atomic_write_text
    from sclam_ros.io.export import export_text, load_calibration

    params = SclamParams.from_yaml(args.params) if args.params else None
    calibration = load_calibration(args.calibration, params)
    if calibration.kept_nominal:
        log.warning("not observable, exported at the nominal value: %s",
                    ", ".join(calibration.kept_nominal))
    text = export_text(calibration, args.format, args.calibration, params, args.controller)
    if args.out:
        atomic_write_text(args.out, text)
        print(f"{args.format}: {args.out}")
    else:
        print(text, end="")
    return 0
