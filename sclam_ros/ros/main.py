"""``sclam_node``: the node's command line. Its parameters files are checked before rcl
reads them (bad YAML is one line, not an RCLError naming C sources), ``--help`` lists the
parameters and starts nothing, and the node spins until it is shut down."""
from __future__ import annotations

import argparse
import sys
from dataclasses import fields
from typing import Optional

import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.impl.implementation_singleton import rclpy_implementation
from rclpy.utilities import remove_ros_args

from sclam_ros.core.params import ParamsError, SclamParams, read_yaml_document
from sclam_ros.ros import node as node_module
from sclam_ros.ros.node import SclamNode


def _argument_parser() -> argparse.ArgumentParser:
    """The node's own command line: only --help (everything else is a ROS argument)."""
    listed = []
    for f in fields(SclamParams):
        default = f"{f.default!r} {f.metadata.get('unit', '')}".strip()
        listed.append(f"  {f.name} = {default}: {f.metadata.get('doc', '')}")
    return argparse.ArgumentParser(
        prog="sclam_node", description=node_module.__doc__,
        usage="sclam_node [-h] [--ros-args --params-file PARAMS.yaml [-p NAME:=VALUE ...]]",
        epilog="parameters (defaults):\n" + "\n".join(listed),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )


def _params_files(argv) -> list:
    return [argv[i + 1] for i, arg in enumerate(argv[:-1]) if arg == "--params-file"]


def _refuse(exc) -> int:
    """One line on stderr and exit status 2, as `sclam` does for input it cannot use."""
    print(f"sclam_node: error: {' '.join(str(exc).split())}", file=sys.stderr)
    return 2


def main(args=None) -> int:
    argv = sys.argv if args is None else list(args)
    try:
        # rcl reads the parameters files whenever it parses the arguments, and on bad YAML
        # fails with an RCLError naming its C source lines: checked here first.
        for path in _params_files(argv):
            read_yaml_document(path)
        # Before rclpy.init: --help starts nothing.
        _argument_parser().parse_args(remove_ros_args(argv)[1:])
        rclpy.init(args=argv)
    except (ParamsError, rclpy_implementation.RCLError) as exc:
        return _refuse(exc)
    node: Optional[SclamNode] = None
    try:
        node = SclamNode()
        rclpy.spin(node)
    except ParamsError as exc:
        return _refuse(exc)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except rclpy_implementation.RCLError:
        # SIGINT shuts the context down; when that lands while the executor builds its
        # wait set, spin raises RCLError ("context is not valid") instead of
        # ExternalShutdownException (test_node's console-script test, once in CI).
        if rclpy.ok():
            raise
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
