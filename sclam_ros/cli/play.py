"""``sclam play BAG``: publish a rosbag2 recording on the live ROS graph.

Every topic whose message type rclpy can import is published with its original timing
(record times, scaled by --rate), so ``sclam_node`` can be tried without a robot::

    sclam_node --ros-args -p use_sim_time:=true --params-file BAG/params.yaml &
    sclam play BAG --clock

The publishing itself (rclpy) lives in :mod:`sclam_ros.ros.player`.
"""
from __future__ import annotations

import argparse


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("bag", help="rosbag2 folder, .db3 or .mcap file")
    parser.add_argument("--rate", type=float, default=1.0,
                        help="playback speed factor (default: %(default)s)")
    parser.add_argument("--clock", action="store_true",
                        help="publish /clock (rosgraph_msgs/Clock) with the record times, for "
                        "nodes with use_sim_time:=true")
    parser.add_argument("--loop", action="store_true", help="start again at the end, until Ctrl-C")
    parser.add_argument("--topics", nargs="+", metavar="TOPIC",
                        help="publish only these topics (default: all with a known type)")
    parser.add_argument("--wait-for-subscribers", type=float, default=0.0, metavar="SECONDS",
                        help="before playing, wait up to SECONDS until every topic has a subscriber")


def run(args) -> int:
    """A missing or corrupt bag, or an unknown topic, propagates as BagError to
    sclam_ros.cli.main (one line, exit status 2); SIGINT and SIGTERM end playback cleanly."""
    from sclam_ros.cli.main import CommandError
    from sclam_ros.ros.player import play

    if not args.rate > 0:
        raise CommandError(f"--rate must be > 0, got {args.rate}")
    return play(args)
