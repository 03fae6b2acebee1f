"""Simulator that writes rosbag2 recordings with ground truth (see ``record.simulate``).
May import: core, io."""
from sclam_ros.sim.record import simulate

__all__ = ["simulate"]
