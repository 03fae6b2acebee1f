"""Simulator that writes rosbag2 recordings with ground truth (see ``record.simulate``)."""
from sclam_ros.sim.record import simulate

__all__ = ["simulate"]
