"""Candidate explanations of residual structure, per odometry edge.

Each regressor is a group of one or more columns: a cause that needs two numbers to be
written linearly (a position on the map, a heading, a wheel's angle with unknown phase)
is one group, so that it competes with the one-column causes as one explanation.
"""
from __future__ import annotations

import numpy as np

from sclam_ros.core import kinematics


def _gradient(values, times):
    out = np.zeros_like(values)
    if len(values) > 2:
        order = np.argsort(times)
        out[order] = np.gradient(values[order], times[order])
    return out


def regressors(inputs, data, wheel_angles, k, poses) -> dict:
    """name -> (m_o, c) array over the odometry edges (c columns of one explanation)."""
    i, j = inputs.odo_from, inputs.odo_from + 1
    t = data.stamps
    dt = np.maximum(t[j] - t[i], 1e-3)
    s, theta = kinematics.arc_length_and_rotation(inputs.odo_dphi, k)
    v, w = s / dt, theta / dt
    mid = 0.5 * (t[i] + t[j])
    r = np.asarray(k, float)
    body_w = (data.wheel_speeds[:, 1] * r[1] - data.wheel_speeds[:, 0] * r[0]) / r[2]
    pos = 0.5 * (poses[i, :2] + poses[j, :2])
    heading = poses[i, 2] + 0.5 * theta
    groups = {
        "v": v,
        "abs_v": np.abs(v),
        # Signed square: a forward error growing with speed keeps the sign of travel.
        "v_squared": v * np.abs(v),
        "omega": w,
        "abs_omega": np.abs(w),
        "v_times_omega": v * w,
        "acceleration": _gradient(v, mid),
        "angular_acceleration": _gradient(w, mid),
        "wheel_speed_change": body_w[j] - body_w[i],  # what an encoder/laser clock offset scales
        "time": mid - t[0],
        "distance": np.cumsum(np.abs(s)),
        "heading": np.column_stack([np.cos(heading), np.sin(heading)]),
        "position": pos,
    }
    # A radius varying once per wheel revolution, r·(1 + a·sin(φ + c)), changes an edge's
    # wheel rotation by ≈ a·(cos(φ_j + c) − cos(φ_i + c)): a combination of the sine and
    # cosine differences, whatever the (unknown) phase c.
    for side, c in (("left", 0), ("right", 1)):
        groups[f"wheel_angle_{side}"] = np.column_stack([
            np.sin(wheel_angles[j, c]) - np.sin(wheel_angles[i, c]),
            np.cos(wheel_angles[j, c]) - np.cos(wheel_angles[i, c])])
    return {name: np.asarray(x, float).reshape(len(v), -1) for name, x in groups.items()}

