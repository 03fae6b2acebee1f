"""The `sclam` command: one subcommand per job, each in sclam_ros/cli/."""
from __future__ import annotations

import argparse
import importlib
import logging
import sys

COMMANDS = {
    "calibrate": "Calibrate wheel radii, wheel base and laser pose from a rosbag2 recording",
    "simulate": "Write a simulated rosbag2 recording with ground truth",
    "play": "Publish a rosbag2 recording on the live ROS graph with its original timing",
    "convert": "Convert a published real-robot log (breezyslam, optiodom) to rosbag2 + params.yaml",
    "diagnose": "Test the calibrated model's residuals and select missing effects on held-out data",
    "fleet": "Calibrate many recordings on Dask (local or a cluster); `fleet report`: history, changes",
}


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="sclam",
        description="Simultaneous calibration, localization and mapping for differential-drive "
        "robots (wheel encoders + 2D laser).",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name, help_text in COMMANDS.items():
        module = importlib.import_module(f"sclam_ros.cli.{name}")
        p = sub.add_parser(name, help=help_text, description=module.__doc__,
                           formatter_class=argparse.RawDescriptionHelpFormatter)
        module.add_arguments(p)
        p.set_defaults(_module=module)
    return parser


def main(argv=None) -> int:
    logging.basicConfig(level=logging.INFO, format="[sclam] %(levelname)s: %(message)s")
    args = build_parser().parse_args(argv)
    try:
        return args._module.run(args)
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
