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
    "export": "Write a calibration as a URDF joint, a diff_drive_controller block or a params YAML",
    "fleet": "Calibrate many recordings on Dask (local or a cluster); `fleet report`: history, changes",
}


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The parser; with `command`, only that subcommand's module is imported (the others are
    listed by name): importing every command (diagnose pulls in scipy.stats, simulate the
    simulator) cost each run about 3 s before it started."""
    parser = argparse.ArgumentParser(
        prog="sclam",
        description="Simultaneous calibration, localization and mapping for differential-drive "
        "robots (wheel encoders + 2D laser).",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name, help_text in COMMANDS.items():
        if command is not None and name != command:
            sub.add_parser(name, help=help_text)
            continue
        module = importlib.import_module(f"sclam_ros.cli.{name}")
        p = sub.add_parser(name, help=help_text, description=module.__doc__,
                           formatter_class=argparse.RawDescriptionHelpFormatter)
        module.add_arguments(p)
        p.set_defaults(_module=module)
    return parser


def _command_in(argv) -> str | None:
    """The subcommand named in `argv` (its first word that is one), or None."""
    for word in argv:
        if not word.startswith("-"):
            return word if word in COMMANDS else None
    return None


# Exit status of a command whose input is unusable (argparse uses it for bad arguments).
INPUT_ERROR_STATUS = 2


class CommandError(ValueError):
    """Arguments a command finds unusable beyond what argparse checks (one line, exit 2)."""


def input_errors() -> tuple:
    """The exceptions that mean "this input cannot be used", whatever the command: each
    carries a message for the user, so they end in one line and exit status 2, never in a
    traceback. Imported when needed: `sclam --help` should not pay for rosbags."""
    import json

    from sclam_ros.core.estimator import CalibrationError
    from sclam_ros.core.params import ParamsError
    from sclam_ros.fleet.recordings import RecordingsError
    from sclam_ros.io.bag import BagError
    from sclam_ros.io.convert import ConvertError
    from sclam_ros.io.export import ExportError
    from sclam_ros.io.tf_static import LaserMountError
    from sclam_ros.io.truth import TruthError
    from sclam_ros.io.zero_config import InferenceError

    # OSError: a path that is a folder, unreadable, or not writable; JSONDecodeError: a JSON input.
    return (CommandError, ParamsError, BagError, CalibrationError, ConvertError, ExportError,
            LaserMountError, RecordingsError, TruthError, InferenceError,
            OSError, json.JSONDecodeError)


def one_line(exc: BaseException) -> str:
    """The reason an exception gives, on one line: some messages list topics or problems
    one per line, and the contract is a single `sclam <command>: error: <reason>` line."""
    if isinstance(exc, OSError) and exc.strerror:
        text = f"{exc.strerror}: {exc.filename}" if exc.filename else exc.strerror
    else:
        text = str(exc) or type(exc).__name__
    lines = [line.strip() for line in text.splitlines() if line.strip()]
    out = lines[0] if lines else type(exc).__name__
    for line in lines[1:]:
        out += (" " if out.endswith(":") else "; ") + line
    return out


class _LowerCaseLevel(logging.Formatter):
    """`sclam calibrate: warning: ...`, in the form of the `sclam calibrate: error: ...` line."""

    def format(self, record):
        record = logging.makeLogRecord(record.__dict__)  # other handlers see the record as it was
        record.levelname = record.levelname.lower()
        return super().format(record)


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    args = build_parser(_command_in(argv)).parse_args(argv)
    logging.basicConfig(level=logging.INFO)
    for handler in logging.getLogger().handlers:
        if type(handler) is logging.StreamHandler:  # basicConfig's (a test harness has its own)
            handler.setFormatter(
                _LowerCaseLevel(f"sclam {args.command}: %(levelname)s: %(message)s"))
    try:
        return args._module.run(args)
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    except Exception as exc:
        if not isinstance(exc, input_errors()):
            raise  # a bug: its traceback is what a report needs
        print(f"sclam {args.command}: error: {one_line(exc)}", file=sys.stderr)
        return INPUT_ERROR_STATUS


if __name__ == "__main__":
    sys.exit(main())
