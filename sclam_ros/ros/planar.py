"""A planar pose's yaw and a planar (x, y, yaw) covariance in ROS messages' 3D fields."""
from __future__ import annotations

import math

import numpy as np


def set_yaw(q, yaw) -> None:
    """Quaternion message q as a rotation by yaw (rad) about z."""
    q.x, q.y, q.z, q.w = 0.0, 0.0, math.sin(0.5 * yaw), math.cos(0.5 * yaw)


def covariance36(cov3) -> list:
    """A 3×3 (x, y, yaw) covariance in the x, y, yaw slots of a row-major 6×6 (in plain
    Python: ~/odom builds two per encoder message)."""
    out = [0.0] * 36
    for row, values in zip((0, 6, 30), np.asarray(cov3, float).tolist()):
        out[row], out[row + 1], out[row + 5] = values
    return out
